"""Splat file formats, one module each; every module's ``FORMAT`` (a
:class:`~abcgs.splats.contract.SplatFormatSpec`) is found by :mod:`abcgs.splats.registry`, so adding a format is
adding a module here (and its name to :data:`abcgs.types.SplatFormat`, which ``params.yaml`` accepts).

- :mod:`.inria` (INRIA output folders), :mod:`.ply` (any INRIA-layout PLY), :mod:`.gsplat_ply`, :mod:`.opensplat`,
  :mod:`.splatfacto` (PLYs in their trainer's frame), :mod:`.gsplat_ckpt` (gsplat checkpoints),
  :mod:`.supersplat` (compressed PLY), :mod:`.splat` (antimatter15), :mod:`.spz` (Niantic, with the export stage's
  PLY → ``.spz`` conversion).
"""
