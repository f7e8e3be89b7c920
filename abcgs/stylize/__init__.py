"""The stylization stage (paper Sec. "Stylization"): colour match, then the optimisation loop.

- :mod:`abcgs.stylize.color`      — the linear colour transform (mean and covariance match), its per-group application
  (to a model's DC colours: ``color_match_model``) and colour preservation.
- :mod:`abcgs.stylize.colormatch` — colour match per matching group, applied to images and Gaussians, and the re-fit.
- :mod:`abcgs.stylize.loop`       — Eq. 8: the stylization run (``stylize``, ``stylize_scene``): targets, the passes,
  colour preservation.
- :mod:`abcgs.stylize.records`    — what a stylization records (logged steps, timings, ``stylize.json``'s numbers).
- :mod:`abcgs.stylize.targets`    — the per-view targets of the style pass (content features, depth, group masks).
- :mod:`abcgs.stylize.passes`     — the two optimisation passes: FAST (or a baseline) + content, TV, depth, scale and
  opacity terms; the authors' colour pass.
- :mod:`abcgs.stylize.experiment` — what a stage loads for one experiment (scene, masks, groups, VGG).
- :mod:`abcgs.stylize.outputs`    — what a stylization run writes (PLY, renders, grid, turntable, loss history).
"""
