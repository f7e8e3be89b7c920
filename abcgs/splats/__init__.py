"""Trained splats in and out: every common 3DGS file format (:mod:`.formats`, one module each, found by
:mod:`.registry`, which reads them into the scene's frame and writes them back in the source's format and frame),
checked against the photos (:mod:`.validate`), imported by the ``fit`` stage in place of a fit (:mod:`.importing`),
given back by the ``export`` stage (:mod:`.exporting`), and cameras made around a splat that has none
(:mod:`.cameras`)."""
