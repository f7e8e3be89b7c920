"""gsplat ``simple_trainer`` checkpoints: ``ckpts/ckpt_<step>_rank0.pt``, a ``torch.save`` of
``{"step": int, "splats": state_dict}`` whose ``splats`` hold ``means (N, 3)``, ``quats (N, 4)`` wxyz, ``scales``
``(N, 3)`` log, ``opacities (N,)`` logits, ``sh0 (N, 1, 3)``, ``shN (N, K-1, 3)`` — the fields of
:class:`~abcgs.gaussians.GaussianModel` under other names. The values are in gsplat's normalised world
(:func:`abcgs.splats.frames.gsplat_similarity`). Checkpoints trained with appearance embeddings (``features`` and
``colors`` instead of ``sh0``/``shN``) have no per-Gaussian SH to import and are refused.
"""

from __future__ import annotations

import io
import os
import warnings
from pathlib import Path

import torch

from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel
from abcgs.io.atomic import write_stream
from abcgs.sfm.align import Similarity
from abcgs.splats import frames
from abcgs.splats.contract import SplatFormatSpec, SplatProvenance, needs_scene, read_bytes

FIELDS = {"means": "means", "quats": "quats", "scales": "log_scales", "opacities": "opacity_logits", "sh0": "sh0",
          "shN": "shN"}
"""gsplat's name → :class:`GaussianModel` field."""


def read_gsplat_ckpt(path: str | os.PathLike) -> tuple[GaussianModel, int | None]:
    """The Gaussians of a gsplat checkpoint and its step (``None`` when absent)."""
    path = Path(path)
    raw = read_bytes(path, "gsplat checkpoint")
    try:
        with warnings.catch_warnings():  # a file's pickle protocol is no warning for the user, its refusal is below
            warnings.simplefilter("ignore")
            data = torch.load(io.BytesIO(raw), map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for a file that is not a checkpoint
        reason = " ".join(str(exc).split())[:200]  # torch's own messages run over several lines
        raise InputError(f"{path} is not a torch checkpoint readable without code ({type(exc).__name__}: {reason}); "
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
    fields = {FIELDS[k]: _real_tensor(path, k, splats[k]) for k in FIELDS}
    try:
        model = GaussianModel(**fields)
    except InputError as exc:  # a shape of another layout
        raise InputError(f"{path}: {exc}; a gsplat checkpoint holds means (N, 3), quats (N, 4), scales (N, 3), "
                         "opacities (N,), sh0 (N, 1, 3), shN (N, K-1, 3)") from None
    return model, _step(path, data.get("step"))


def _real_tensor(path: Path, key: str, value: object) -> torch.Tensor:
    """``splats[key]`` as a contiguous CPU ``float32`` tensor; :class:`InputError` naming ``path`` and ``key`` when it
    is not a tensor of at least one dimension and a real floating-point (or integer) dtype (a complex tensor would
    lose its imaginary part)."""
    if not isinstance(value, torch.Tensor):
        raise InputError(f"{path}: splats['{key}'] is a {type(value).__name__}, not a tensor; the file is not a gsplat "
                         "checkpoint")
    if value.dim() == 0 or value.is_complex() or value.dtype == torch.bool:
        raise InputError(f"{path}: splats['{key}'] is a {value.dim()}-d {value.dtype} tensor; gsplat saves real "
                         "floating-point tensors with one row per Gaussian")
    return value.detach().to("cpu", torch.float32).contiguous()


def _step(path: Path, step: object) -> int | None:
    """The checkpoint's ``step`` (``None`` when absent): a whole number from 0 to 10¹²; :class:`InputError` naming
    ``path`` otherwise (a string, an infinite float)."""
    if step is None:
        return None
    if isinstance(step, torch.Tensor) and step.numel() == 1 and not step.is_complex():
        step = step.item()
    if isinstance(step, bool) or not isinstance(step, (int, float)) or not (0 <= step <= 1e12 and step == int(step)):
        raise InputError(f"{path}: step is {str(step)[:40]!r}, not an iteration count (a whole number from 0 to "
                         "1e12); the file is not a gsplat checkpoint")
    return int(step)


def write_gsplat_ckpt(path: str | os.PathLike, model: GaussianModel, step: int | None = None) -> None:
    """Write ``model`` as a gsplat checkpoint (gsplat's ``--ckpt`` loads it for rendering and evaluation)."""
    inverse = {v: k for k, v in FIELDS.items()}
    splats = {inverse[name]: t.detach().to("cpu", torch.float32).contiguous() for name, t in model.items()}
    write_stream(path, lambda fh: torch.save({"step": int(step or 0), "splats": splats}, fh))


def _read(path: Path, drop_invalid: bool) -> tuple[GaussianModel, dict]:
    model, step = read_gsplat_ckpt(path)
    return model, {"step": step}


def _frame(path: Path, scene, fields: dict) -> Similarity:
    """Scene → file: gsplat's ``normalize_world_space`` of the scene's cameras and points."""
    needs_scene("gsplat_ckpt", scene)
    return frames.gsplat_similarity(scene.cameras, scene.points)


def _write(model: GaussianModel, path: Path, like: SplatProvenance) -> None:
    write_gsplat_ckpt(path, model, like.step)


FORMAT = SplatFormatSpec("gsplat_ckpt", _read, _write, _frame,
                         detect=lambda p: p.suffix.lower() in (".pt", ".pth", ".ckpt"), rank=40,
                         suffixes=(".pt", ".pth", ".ckpt"))
