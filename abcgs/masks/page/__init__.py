"""Masks from strokes: GrabCut guided by a user's scribbles (Rother et al. 2004), drawn on a local web page.

    python -m abcgs.masks.page data/tiny                      # views of <scene>/images/ → <scene>/masks/<stem>.png
    python -m abcgs.masks.page /data/garden --images images_4 # views of <scene>/images_4/ (or of a dataset)
    python -m abcgs.masks.page --scene tiny                   # data.scenes.tiny of params.yaml, with its fit if any
    python -m abcgs.masks.page /data/s --fit out/s/gs/point_cloud.ply --colmap out/s/colmap  # a folder and its fit
    python -m abcgs.masks.page data/tiny --painting data/tiny/styles/paint.png \\
        --labels-out data/tiny/styles/paint_labels.png         # one painting → its region label map

The page (``static/paint.html``, plain JavaScript, nothing fetched from the network) is served on 127.0.0.1 to
itself only, by :mod:`abcgs.masks.page.server`: the address printed at start carries a random token (as Jupyter's
does), and a request from anything but that page is refused with a one-line reason. Pick a label, draw strokes over
the objects of one or more views, press **Segment** to see the cut over the view, add strokes where it is wrong, and
press **Save**: every view with strokes gets a single-channel label PNG (1, 2, … the labels; 0 = no label, what the
background brush or its cut decided; 255 = :data:`~abcgs.masks.params.UNDECIDED`, what no cut claimed; the format
:func:`abcgs.masks.content.read_label_files` reads), written atomically, and its strokes as a seed map in
``<scene>/masks/strokes/<stem>.png`` (the ``masks`` stage binds the Gaussians under them, as the page does). Views
without strokes get no file: the ``masks`` stage lifts labels from any subset of views. The views are the ones the
pipeline reads (:func:`~abcgs.masks.page.session.scene_views`: a scene's ``images:`` folder, a dataset's views, a bare splat's views made by
the ``reconstruct`` stage), and the label maps go to ``<scene>/masks/``, where that stage reads them.

**With the scene's fit** (``--scene NAME`` once ``dvc repro fit@NAME`` has made ``out/NAME/gs/point_cloud.ply``,
with ``masks.field`` and ``masks.lift`` of the params file; or ``--fit PLY --colmap DIR``), the page's views are
matched to the fit's cameras by image stem, and each Segment carries the labels to every view
(:mod:`abcgs.masks.page.field_session`): the view is cut from its strokes and the labels already in 3-D
(:func:`abcgs.masks.field.cut_painted_view`), every painted view is lifted onto the Gaussians, the rest is decided
in 3-D, and a strip under the view shows every view's labels (undecided white), most doubtful first; a click opens a
view. Without a fit, or when a matched view is not its camera's size, the page says why (and which command makes the
fit) and cuts one view at a time on colour alone (:func:`abcgs.masks.grabcut.segment`; ``--one-view`` asks for
that).

The room's modules:

- :mod:`~abcgs.masks.page.command` — the command line (``python -m abcgs.masks.page``).
- :mod:`~abcgs.masks.page.session` — the page's state: its views or painting, their strokes, cuts and saved maps.
- :mod:`~abcgs.masks.page.field_session` — with a fit: each Segment carried to every view through the Gaussians.
- :mod:`~abcgs.masks.page.strip` — the strip of every view's labels under the painted one, rendered incrementally.
- :mod:`~abcgs.masks.page.server` — the HTTP server on 127.0.0.1, behind :class:`~abcgs.masks.page.server.PageSession`.
- :mod:`~abcgs.masks.page.requests` — the bounded, validated reading of the page's JSON requests.

The strokes and segmentations it exchanges with the algorithm are :mod:`abcgs.masks.strokes`.
"""
