"""Step counts chosen by the scene's view size: the stylization's main and colour passes and the colour match's
re-fit, where ``params.yaml`` leaves them unset (``null``).

    schedule = choose_schedule(cameras, main=None, color_pass=200)   # None: unset in params.yaml
    schedule.steps["main"], schedule.steps["color_pass"], schedule.name, schedule.reason

Views of at most :data:`SHORT_MAX_PIXELS` pixels (after ``resolution_scale``; the embedded tiny scene's are
160 × 120) take the :data:`SHORT` counts, larger views the :data:`PHOTO` counts, the one every measurement on
photo-sized scenes in docs/FIDELITY.md used. A count set in ``params.yaml`` is kept. Each stage's record holds
:meth:`Schedule.to_dict`: the counts, the schedule's name and why it was chosen.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from abcgs.cameras import Camera

SHORT_MAX_PIXELS = 100_000
"""The largest median view (pixels) that takes the short schedule: about 365 × 274."""


@dataclass(frozen=True)
class Schedule:
    """Step counts of one stage and where they come from.

    Attributes:
        steps: the counts the stage asked for, by name: ``main`` (the stylization's main pass), ``color_pass`` (the
        authors' colour pass after it), ``refit`` (the colour match's re-fit on the recoloured photos); each ≥ 0.
        name: ``short`` | ``photo`` (the size's schedule) | ``set`` (every count from params.yaml).
        reason: one sentence saying why.
    """

    steps: dict[str, int]
    name: str
    reason: str

    def to_dict(self) -> dict:
        return asdict(self)


SHORT = {"main": 150, "color_pass": 50, "refit": 100}
"""Small views (the embedded tiny scene): 150 + 50 stylization steps, a 100-step re-fit."""

PHOTO = {"main": 300, "color_pass": 200, "refit": 400}
"""Photo-sized views: 300 + 200 stylization steps (docs/FIDELITY.md), the authors' 400-step re-fit."""


def median_pixels(cameras: Sequence[Camera], scale: float = 1.0) -> int:
    """The median view's pixel count at ``scale`` of the cameras' size."""
    if not cameras:
        return 0
    return int(np.median([round(c.width * scale) * round(c.height * scale) for c in cameras]))


def choose_schedule(cameras: Sequence[Camera], scale: float = 1.0, **given: int | None) -> Schedule:
    """The step counts named in ``given`` (``main``, ``color_pass``, ``refit``: the params.yaml value, None where
    unset) for a scene whose views are ``cameras`` rendered at ``scale``: each unset one from the views' size."""
    unknown = set(given) - set(SHORT)
    if unknown:
        raise ValueError(f"choose_schedule: unknown step counts {sorted(unknown)} (known: {', '.join(SHORT)})")
    pixels = median_pixels(cameras, scale)
    short = pixels <= SHORT_MAX_PIXELS
    by_size, name = (SHORT, "short") if short else (PHOTO, "photo")
    steps = {k: by_size[k] if v is None else int(v) for k, v in given.items()}
    kept = [k for k, v in given.items() if v is not None]
    if given and len(kept) == len(given):
        return Schedule(steps, "set", "set in params.yaml")
    reason = (f"median view {pixels:,} pixels {'<=' if short else '>'} {SHORT_MAX_PIXELS:,}: the {name} schedule"
              + (f" ({', '.join(kept)} set in params.yaml)" if kept else ""))
    return Schedule(steps, name, reason)
