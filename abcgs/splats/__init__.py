"""Trained splats in and out: every common 3DGS file format read into the scene's frame (:mod:`.formats`), checked
against the photos (:mod:`.validate`), imported by the ``fit`` stage in place of a fit (:mod:`.importing`), given
back in the source's format and frame (:func:`.formats.write_splat`), and cameras made around a splat that has none
(:mod:`.cameras`)."""
