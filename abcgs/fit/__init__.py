"""Baseline 3DGS fitting (Kerbl et al. 2023).

- :mod:`abcgs.fit.params`   — the ``fit`` section: schedule, learning rates, densification settings.
- :mod:`abcgs.fit.losses`   — ``0.8·L1 + 0.2·D-SSIM`` with the fused CPU kernel and its torch reference.
- :mod:`abcgs.fit.strategy` — densification: clone, split, prune, opacity reset.
- :mod:`abcgs.fit.trainer`  — the training loop, held-out evaluation and the stage's outputs.
- :mod:`abcgs.fit.metrics`  — PSNR and SSIM of the held-out views.
"""
