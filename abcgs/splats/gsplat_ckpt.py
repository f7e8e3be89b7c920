"""gsplat ``simple_trainer`` checkpoints: ``ckpts/ckpt_<step>_rank0.pt``, a ``torch.save`` of
``{"step": int, "splats": state_dict}`` whose ``splats`` hold ``means (N, 3)``, ``quats (N, 4)`` wxyz, ``scales``
``(N, 3)`` log, ``opacities (N,)`` logits, ``sh0 (N, 1, 3)``, ``shN (N, K-1, 3)`` — the fields of
:class:`~abcgs.gaussians.GaussianModel` under other names. The values are in gsplat's normalised world
(:func:`abcgs.splats.frames.gsplat_similarity`). Checkpoints trained with appearance embeddings (``features`` and
``colors`` instead of ``sh0``/``shN``) have no per-Gaussian SH to import and are refused.
"""

from __future__ import annotations

import os
from pathlib import Path

import torch

from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel
from abcgs.io.atomic import atomic_path

FIELDS = {"means": "means", "quats": "quats", "scales": "log_scales", "opacities": "opacity_logits", "sh0": "sh0",
          "shN": "shN"}
"""gsplat's name → :class:`GaussianModel` field."""


def read_gsplat_ckpt(path: str | os.PathLike) -> tuple[GaussianModel, int | None]:
    """The Gaussians of a gsplat checkpoint and its step (``None`` when absent)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"gsplat checkpoint {path} does not exist")
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for a file that is not a checkpoint
        raise InputError(f"{path} is not a torch checkpoint readable without code ({type(exc).__name__}: {exc}); "
                         "pass gsplat's ckpts/ckpt_<step>_rank0.pt") from None
    splats = data.get("splats") if isinstance(data, dict) else None
    if not isinstance(splats, dict):
        raise InputError(f"{path} has no 'splats' dictionary; a gsplat simple_trainer checkpoint holds "
                         "{'step', 'splats': {means, quats, scales, opacities, sh0, shN}}")
    if "features" in splats or "colors" in splats:
        raise InputError(f"{path} was trained with appearance embeddings (features/colors, no per-Gaussian SH); "
                         "export it with gsplat's PLY export after baking colours, or retrain without --app_opt")
    missing = [k for k in FIELDS if k not in splats]
    if missing:
        raise InputError(f"{path}: the splats dictionary lacks {', '.join(missing)} (has {', '.join(splats)})")
    fields = {FIELDS[k]: splats[k].detach().to("cpu", torch.float32).contiguous() for k in FIELDS}
    step = data.get("step")
    return GaussianModel(**fields), int(step) if step is not None else None


def write_gsplat_ckpt(path: str | os.PathLike, model: GaussianModel, step: int | None = None) -> None:
    """Write ``model`` as a gsplat checkpoint (gsplat's ``--ckpt`` loads it for rendering and evaluation)."""
    inverse = {v: k for k, v in FIELDS.items()}
    splats = {inverse[name]: t.detach().to("cpu", torch.float32).contiguous() for name, t in model.items()}
    with atomic_path(path) as tmp:
        torch.save({"step": int(step or 0), "splats": splats}, tmp)
