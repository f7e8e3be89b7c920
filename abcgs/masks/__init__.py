"""Content masks and their lifting onto the Gaussians (paper Sec. "Controllable Matching Stage", Eq. 2).

- :mod:`abcgs.masks.content` — the user's label PNGs, or automatic ones (clustering, GrabCut), per view; the
  ``masks`` stage's whole path (:func:`~abcgs.masks.content.make_content_masks`).
- :mod:`abcgs.masks.lifting` — Eq. 2: per-Gaussian label votes from blending weights, rendered back per view.
- :mod:`abcgs.masks.refine`  — the views without a mask re-cut on colour and rendered depth, then lifted from all.
- :mod:`abcgs.masks.grabcut` — GrabCut from strokes or seed maps, on colour and optionally depth.
- :mod:`abcgs.masks.paint`   — the drawing page for strokes on views and paintings: ``python -m abcgs.masks.paint``.
- :mod:`abcgs.masks.outputs` — what the ``masks`` stage writes, and reading it back.
"""
