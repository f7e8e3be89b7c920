"""Scene dataset formats, one module each; every module's ``READER`` (a :class:`~abcgs.sources.base.SceneReader`:
name, detection and its priority, options model, reader) is found by :mod:`abcgs.sources.registry`, so adding a
format is adding a module here (or to a plugin folder, ``ABCGS_READERS``). A module imports only light modules at its
top; its reading code (here: the modules of :mod:`abcgs.sources` named like the format) loads when a scene is read.

==================  ==============================================  ========  =================================
format              the folder holds                                priority  cameras
==================  ==============================================  ========  =================================
:mod:`.blender`     ``transforms_train.json``                       10        read (NeRF-synthetic)
:mod:`.nerfstudio`  ``transforms.json``                             20        read
:mod:`.colmap`      ``sparse/0/cameras.{bin,txt}`` or ``sparse/…``   30        read
:mod:`.llff`        ``poses_bounds.npy``                            40        read
:mod:`.photos`      an image folder (``images/``)                   50        structure from motion
:mod:`.splat`       only a splat file (and ``masks/``)              60        made around the splat
==================  ==============================================  ========  =================================
"""
