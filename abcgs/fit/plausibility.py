"""Is a fitted scene fit to be painted? The checks the ``fit`` stage runs on its result before anything downstream
reads it.

    verdict = check_fit(result)      # FitCheck: both PSNRs, the views, the share of reset opacities
    verdict.raise_if_implausible()   # FitError, one line naming the likely causes

A fit is refused when its held-out views score below ``fit.min_psnr`` (the floor), more than
``fit.max_psnr_gap`` dB below its training views (it learnt the training photos but not the scene), or when at least
:data:`RESET_SHARE` of its Gaussians still have the opacity a reset clamps them to (it ended on an opacity reset). Both PSNRs come
from the final model, rendered the same way: the held-out views (every ``test_every``-th) and up to
:data:`TRAIN_VIEWS` training views spread over the capture. Without held-out views the training views meet the floor.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import torch

from abcgs.errors import AbcgsError
from abcgs.fit.evaluation import evaluate
from abcgs.fit.training import FitResult

TRAIN_VIEWS = 8
"""Training views rendered for the training PSNR (evenly spaced over the training list)."""

RESET_SHARE = 0.9
"""Share of the Gaussians at or under the reset opacity from which the fit is said to have ended on a reset: a reset
on the last step leaves them all there; healthy fits leave the Gaussians that learnt to be empty (the tiny scene:
7-19 %, ``python -m eval run fit_schedule``; 35 % on a 300-step fit of random Gaussians on black)."""


class FitError(AbcgsError):
    """A fit whose renders do not reproduce its photos well enough to be stylized."""


@dataclass
class FitCheck:
    """The numbers behind the verdict (written to the fit's record as ``check``).

    Attributes:
        heldout_psnr: mean PSNR (dB) of the held-out views; None when nothing is held out.
        train_psnr: mean PSNR (dB) of the rendered training views.
        heldout_views, train_views: the view names each PSNR is over.
        min_psnr, max_psnr_gap: the thresholds in force (dB).
        reset_share: share of the Gaussians whose opacity is at or under ``strategy.reset_opacity``.
        problems: the failed checks, each a clause naming its cause; empty when the fit is plausible.
    """

    heldout_psnr: float | None
    train_psnr: float
    heldout_views: list[str]
    train_views: list[str]
    min_psnr: float
    max_psnr_gap: float
    reset_share: float
    problems: list[str]

    def to_dict(self) -> dict:
        return asdict(self)

    def raise_if_implausible(self) -> None:
        if self.problems:
            raise FitError("the fit is implausible: " + "; ".join(self.problems) + ". Nothing downstream runs on "
                           "it; fix the cause, or lower fit.min_psnr / raise fit.max_psnr_gap if the scene is "
                           "really this hard")


def train_sample(train: list[int], k: int = TRAIN_VIEWS) -> list[int]:
    """Up to ``k`` of the training view indices, evenly spaced over the list (deterministic)."""
    if len(train) <= k:
        return list(train)
    return [train[i] for i in np.linspace(0, len(train) - 1, k).round().astype(int)]


def check_fit(result: FitResult) -> FitCheck:
    """Render the training sample with the final model and judge the fit (:class:`FitCheck`)."""
    params = result.params
    picked = train_sample(list(result.views.train))
    cams, imgs = result.views.pick(picked)
    background = torch.tensor(params.background, dtype=torch.float32, device=result.model.device)
    train = evaluate(result.model, cams, imgs, result.backend, background=background)
    heldout = result.heldout
    reset_value = params.strategy_params().reset_opacity
    opacity = torch.sigmoid(result.model.opacity_logits.detach().float())
    reset_share = float((opacity <= reset_value * 1.001).float().mean()) if opacity.numel() else 1.0
    check = FitCheck(
        heldout_psnr=heldout.psnr if heldout is not None else None, train_psnr=train.psnr,
        heldout_views=[v.name for v in heldout.views] if heldout is not None else [],
        train_views=[c.name for c in cams], min_psnr=params.min_psnr, max_psnr_gap=params.max_psnr_gap,
        reset_share=reset_share, problems=[],
    )
    check.problems = problems(check)
    return check


def problems(check: FitCheck) -> list[str]:
    """The failed checks of ``check``'s numbers, each with its likely causes."""
    out = []
    if check.reset_share >= RESET_SHARE:
        out.append(f"{check.reset_share:.0%} of its Gaussians still have the reset opacity: the opacities were reset "
                   "too near the end of the run to be learnt back (fit.strategy.reset_every, refine_stop)")
    scored = check.heldout_psnr if check.heldout_psnr is not None else check.train_psnr
    which = "held-out" if check.heldout_psnr is not None else "training"
    if scored < check.min_psnr:
        causes = ("the opacity reset above" if check.reset_share >= RESET_SHARE else
                  "cameras that do not belong to these images (another scene's, or a wrong axis convention), "
                  "images of another size than the cameras, or too few steps (fit.iterations)")
        out.append(f"its {which} views score {scored:.1f} dB PSNR, under the floor fit.min_psnr = "
                   f"{check.min_psnr:g} dB; likely causes: {causes}")
    if check.heldout_psnr is not None and check.train_psnr - check.heldout_psnr > check.max_psnr_gap:
        out.append(f"its training views score {check.train_psnr:.1f} dB but its held-out views "
                   f"{check.heldout_psnr:.1f} dB, more than fit.max_psnr_gap = {check.max_psnr_gap:g} dB apart: "
                   "it learnt the photos, not the scene; likely causes: cameras that do not match their images, "
                   "too few or too similar views, or a densification schedule that overfits")
    return out
