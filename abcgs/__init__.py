"""abcgs — ABC-GS (alignment-based controllable style transfer for 3D Gaussian Splatting).

Importing abcgs changes nothing in the process: a program calls :func:`abcgs.runtime.setup` before it imports torch
(OpenMP's wait policy, OpenCV before pycolmap). The package, floor by floor (lowest first):

- Foundations: :mod:`abcgs.errors`, :mod:`abcgs.types` (modes and interfaces shared across packages),
  :mod:`abcgs.dotted` (dotted params keys), :mod:`abcgs.sections` (the params sections and their models),
  :mod:`abcgs.progress`, :mod:`abcgs.cameras` (a pinhole view, batched views and their COLMAP lenses),
  :mod:`abcgs.runtime` (setup, device, threads), :mod:`abcgs.plugins` (the registry of format modules),
  :mod:`abcgs.io` (atomic writes, images, metrics records, tables; its ``ply`` and ``spz`` modules, which read
  into :class:`abcgs.gaussians.Gaussians`, are on the rendering floor).
- Rendering: :mod:`abcgs.render` (the differentiable rasterizer: reference, C++ CPU kernels, gsplat),
  :mod:`abcgs.gaussians`, :mod:`abcgs.viz`, :mod:`abcgs.camera_paths`, :mod:`abcgs.silhouette`.
- Scenes and features: :mod:`abcgs.sfm` (structure from motion through pycolmap, COLMAP models),
  :mod:`abcgs.scene` (the embedded synthetic scene), :mod:`abcgs.layout` (every path under ``out/``),
  :mod:`abcgs.features` (VGG features, style isolation, matching groups, neighbour search).
- Losses: :mod:`abcgs.losses` (FAST and the NNFM, KNNFM, Gram baselines; content and TV terms).
- Methods: :mod:`abcgs.sources` (one reader per dataset format; a scene entry to its layout), :mod:`abcgs.splats` (trained splats in and out),
  :mod:`abcgs.fit` (baseline 3DGS), :mod:`abcgs.masks` (content masks lifted onto the Gaussians),
  :mod:`abcgs.stylize` (colour match and stylization), :mod:`abcgs.evaluation` (the metrics).
- Presentation: :mod:`abcgs.view` (the 3-D splat viewer), :mod:`abcgs.report`.
- Orchestration: :mod:`abcgs.params` (the ``params.yaml`` schema), :mod:`abcgs.pipeline` (stage specs),
  :mod:`abcgs.preflight` (with :mod:`abcgs.source_check`: datasets read by their readers; :mod:`abcgs.entry_checks`:
  entry names and label numbers; :mod:`abcgs.dvc_file`: reading ``dvc.yaml``), :mod:`abcgs.dag`
  (``dvc.yaml``), :mod:`abcgs.add` (``python -m abcgs add-scene``, ``add-style``), :mod:`abcgs.add_experiment`
  (``python -m abcgs add-experiment``),
  :mod:`abcgs.overlay`, :mod:`abcgs.cluster` (Slurm job arrays; the ``cluster`` extra).

A module imports only from its own floor or lower ones; ``tests/test_layers.py`` checks it against the floors of
``eval/bench/structure.py``, and ``tests/test_docs.py`` that this map names every package and module.
"""

__version__ = "0.1.0"
