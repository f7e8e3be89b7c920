"""Content masks and their lifting onto the Gaussians (paper Sec. "Controllable Matching Stage", Eq. 2).

- :mod:`abcgs.masks.content` — the user's label PNGs, or automatic ones (clustering, GrabCut), per view.
- :mod:`abcgs.masks.lifting` — Eq. 2: per-Gaussian label votes from blending weights, rendered back per view.
- :mod:`abcgs.masks.outputs` — what the ``masks`` stage writes, and reading it back.
- :mod:`abcgs.masks.paint`   — label maps from a user's strokes (GrabCut) on a local page: ``python -m abcgs.masks.paint``.
"""
