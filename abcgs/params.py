"""The whole ``params.yaml``: every section's model (:data:`abcgs.sections.SECTIONS`) in one :class:`Params`, and its
loader. The preflight stage, which every stage depends on, and the command-line tools validate the whole file, so a
typo anywhere fails before any work with the key's path, what was wrong and the allowed keys or values:

    params.yaml: fit.iteratons: unknown key; allowed keys here: iterations, sh_degree, ...

A stage validates only the sections it reads (:func:`abcgs.sections.validate_sections`).
"""

from __future__ import annotations

import os
from typing import Any

# every section's model, imported here so that code depending on the whole schema depends on each of them
import abcgs.evaluation.params
import abcgs.features.params
import abcgs.fit.params
import abcgs.masks.params
import abcgs.runtime
import abcgs.scene.params
import abcgs.sfm.params
import abcgs.sources.params
import abcgs.stylize.params
import abcgs.view.params
from abcgs.sections import SECTIONS, ParamsBase, params_model, read_params_file, validate_sections

_MODULES = {m.__name__ for m in (abcgs.evaluation.params, abcgs.features.params, abcgs.fit.params,
                                 abcgs.masks.params, abcgs.runtime, abcgs.scene.params, abcgs.sfm.params,
                                 abcgs.sources.params, abcgs.stylize.params, abcgs.view.params)}
assert {s.module for s in SECTIONS.values()} == _MODULES, "abcgs.params imports every module SECTIONS names"

Params: type[ParamsBase] = params_model(frozenset(SECTIONS))
"""The whole ``params.yaml``: one field per section of :data:`abcgs.sections.SECTIONS`."""


def validate_params(raw: Any, source: str = "params.yaml") -> ParamsBase:
    """Validate an already-parsed mapping as the whole file; raise :class:`ParamsError` with every problem listed."""
    return validate_sections(raw, frozenset(SECTIONS), source)


def load_params(path: str | os.PathLike = "params.yaml") -> ParamsBase:
    """Read and validate the whole ``params.yaml``."""
    return validate_params(read_params_file(path), str(path))
