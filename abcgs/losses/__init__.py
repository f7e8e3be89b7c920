"""Stylization losses.

- :mod:`abcgs.losses.fast`  — FAST, the feature-alignment style loss (paper Eq. 5–7).
- :mod:`abcgs.losses.terms` — content and total-variation terms, the NNFM / KNNFM / Gram baselines and the
  ``style_loss`` dispatcher. The depth, scale and opacity terms of Eq. 8 live in the pass that owns their
  reference values (:mod:`abcgs.stylize.passes`).
"""
