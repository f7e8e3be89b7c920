"""Baseline 3DGS fitting (Kerbl et al. 2023).

- :mod:`abcgs.fit.params`     — the ``fit`` section: schedule, learning rates, densification settings.
- :mod:`abcgs.fit.data`       — the scene's views in memory, the train/test split and the scene's extent.
- :mod:`abcgs.fit.losses`     — ``0.8·L1 + 0.2·D-SSIM`` with the fused CPU kernel and its torch reference.
- :mod:`abcgs.fit.strategy`   — densification: the strategy hooks, 3DGS's default, clone/split/prune/reset ops.
- :mod:`abcgs.fit.adam`       — Adam, the update of ``torch.optim.Adam`` bit for bit, without importing torch.compile.
- :mod:`abcgs.fit.training`   — the optimisers, the learning-rate schedule and the training loop.
- :mod:`abcgs.fit.evaluation` — held-out evaluation (PSNR, SSIM per view) and the comparison grid.
- :mod:`abcgs.fit.outputs`    — the stage's files: PLY, metrics, history, held-out grid.
- :mod:`abcgs.fit.metrics`    — PSNR and SSIM of the held-out views.
"""
