"""Content masks and their lifting onto the Gaussians (paper Sec. "Controllable Matching Stage", Eq. 2).

The algorithm:

- :mod:`abcgs.masks.lifting` — Eq. 2: per-Gaussian label votes from blending weights, rendered back per view.
- :mod:`abcgs.masks.graph`   — the 3-D step: a nearest-neighbour graph over the Gaussians and a random walk on it.
- :mod:`abcgs.masks.field`   — a scene's labels from the views a user painted (the page's and the stage's path).
- :mod:`abcgs.masks.edges`   — each view's rendered labels refined against its photo's edges.
- :mod:`abcgs.masks.regions` — a stroke's colour region in its photo (``masks.field.correction: region``).
- :mod:`abcgs.masks.grabcut` — GrabCut from strokes or seed maps, on colour and optionally depth.
- :mod:`abcgs.masks.strokes` — the strokes a user paints and the segmentation a cut makes (types shared with the page).
- :mod:`abcgs.masks.refine`  — ``masks.refine``: views without a mask re-cut on colour and rendered depth, then lifted.
- :mod:`abcgs.masks.spread`  — labels spread along the Gaussians' surfaces to what no labelled view sees.

The stage and its settings:

- :mod:`abcgs.masks.content` — the user's label PNGs, or automatic ones (clustering, GrabCut), per view; the
  ``masks`` stage's whole path (:func:`~abcgs.masks.content.make_content_masks`).
- :mod:`abcgs.masks.outputs` — what the ``masks`` stage writes, and reading it back.
- :mod:`abcgs.masks.params`  — the ``masks`` section's schema.

The page: :mod:`abcgs.masks.page`, a room of its own (strokes on views and paintings, ``python -m abcgs.masks.page``).
"""
