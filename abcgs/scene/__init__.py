"""The embedded synthetic default scene (see :mod:`abcgs.scene.synthetic`)."""
