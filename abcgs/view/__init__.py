"""The 3-D splat viewer: a self-contained page of original, stylized and label layers over one scene.

- :mod:`abcgs.view.page`    — the page and the per-experiment data it embeds.
- :mod:`abcgs.view.outputs` — loading an experiment's outputs for the page.
- :mod:`abcgs.view.params`  — the ``viewer`` section of ``params.yaml``.
- ``python -m abcgs.view out/<experiment>`` writes one experiment's page.
"""
