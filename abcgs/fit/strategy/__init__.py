"""Pluggable densification strategies (the shape of gsplat's ``Strategy`` API).

A strategy owns no parameters. The trainer calls two hooks around each optimisation step::

    state = strategy.initialize_state(model)
    for step in 1..T:
        image, alpha, meta = render(model, camera)
        strategy.step_pre_backward(model, optimizers, state, step, meta)   # e.g. meta.means2d.retain_grad()
        loss.backward(); [opt.step() for opt in optimizers.values()]
        strategy.step_post_backward(model, optimizers, state, step, meta)  # grow / prune / reset

``model`` is a :class:`~abcgs.gaussians.GaussianModel` whose fields are ``nn.Parameter`` s and
``optimizers`` maps each field name to the optimiser that updates it. Hooks that add or remove
Gaussians do so through the operations of :mod:`~abcgs.fit.strategy.ops` (``duplicate``, ``split``,
``remove``, ``reset_opacity``), which replace the model's tensors and keep every optimiser's
per-parameter state (Adam's ``exp_avg``/``exp_avg_sq``) the same length as its parameter.

- :mod:`~abcgs.fit.strategy.base`    — the :class:`Strategy` hooks, :class:`RefineReport`, :class:`NoDensification`
  (keeps the set of Gaussians fixed: stylization).
- :mod:`~abcgs.fit.strategy.default` — :class:`DefaultStrategy`, the adaptive density control of 3DGS.
- :mod:`~abcgs.fit.strategy.ops`     — the tensor operations on a model and its optimisers.
"""

from abcgs.fit.strategy.base import NoDensification, RefineReport, Strategy
from abcgs.fit.strategy.default import DefaultStrategy
from abcgs.fit.strategy.ops import Optimizers, State

__all__ = ["DefaultStrategy", "NoDensification", "Optimizers", "RefineReport", "State", "Strategy"]
