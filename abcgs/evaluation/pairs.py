"""Which views the consistency metrics compare: neighbours along a path through the cameras, or file order.

The paper measures consistency on a rendered video: frames ``t, t + 1`` (short-range) and ``t, t + 7``
(long-range). Training views carry no such order; their file names may follow the capture or not. With
``evaluate.pairs: pose`` the views are first put in an order along a path through the camera poses
(:func:`pose_path`), and the pairs are taken along that path exactly as along a video:

- **short-range**: views ``short_term_gap`` (1) apart on the path, i.e. each view and the next one;
- **long-range**: views ``long_term_gap`` (7) apart on the path, the gap clipped to ``n − 1``.

``n − gap`` pairs of each kind, the same counts as in file order. The pairs depend on the poses only, never on
the order the cameras come in (names break exact ties and orient the path). ``evaluate.pairs: index`` keeps the
views in list (file-name) order: pairs ``(i, i + gap)``.

**Pose distance** between views ``a`` and ``b`` (:func:`pose_distances`), in units of the scene's typical
neighbour step::

    d(a, b) = sqrt( (‖c_a − c_b‖ / s)² + (θ_ab / s_θ)² )

``c``: camera centre (world units); ``θ_ab``: angle between the two viewing directions (the cameras' +z axes,
radians); ``s``: the median over views of the distance to the nearest other distinct centre; ``s_θ``: the median
over views of the angle to the nearest other distinct viewing direction, at least :data:`MIN_ANGLE_SCALE` (0.1°,
about a pixel of image motion at common focal lengths, so that numerically identical directions do not inflate
noise). A term whose scale is 0 (every camera at one place, or all looking one way) is left out.

**Path** (:func:`pose_path`): a greedy nearest-neighbour chain in ``d`` from an end of the pose diameter (the two
views farthest apart; of the two chains the shorter in total length), then shortened by 2-opt moves (reversing a
stretch of the path whenever that shortens it) until none helps. A straight-line or orbit capture gives its
capture order; scattered captures (a hand-held grid, photos in any order) a path through neighbours. The path
runs from the end whose view name sorts first.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from abcgs.cameras import Camera
from abcgs.errors import InputError

PairMode = Literal["pose", "index"]
MIN_ANGLE_SCALE = float(np.deg2rad(0.1))
"""Lower bound of the angle scale ``s_θ`` (radians)."""
_REL_TOL = 1e-9  # distances within this relative tolerance count as ties (broken by view name)


@dataclass(frozen=True)
class ViewPairs:
    """The consistency pairs of one view set: ``(i, j)`` = view ``j`` warped into view ``i`` (list indices)."""

    mode: str
    order: list[int]  # the views along the path (``index``: 0 … n − 1)
    short: list[tuple[int, int]]
    long: list[tuple[int, int]]
    short_gap: int  # the gaps on the path, after clipping to n − 1
    long_gap: int

    def of(self, kind: str) -> list[tuple[int, int]]:
        """``kind``: ``short`` or ``long``."""
        return {"short": self.short, "long": self.long}[kind]

    def to_json(self) -> dict:
        return {"mode": self.mode, "order": list(self.order), "short_gap": self.short_gap, "long_gap": self.long_gap,
                "short": [list(p) for p in self.short], "long": [list(p) for p in self.long]}


def clipped_gap(n: int, gap: int) -> int:
    """``gap`` clipped to ``[1, n − 1]``; at least 2 views."""
    if n < 2:
        raise InputError(f"consistency needs at least 2 views, got {n}")
    return max(1, min(gap, n - 1))


def path_pairs(order: Sequence[int], gap: int) -> list[tuple[int, int]]:
    """``(order[k], order[k + g])`` for every k, with ``g`` = :func:`clipped_gap`."""
    g = clipped_gap(len(order), gap)
    return [(int(order[k]), int(order[k + g])) for k in range(len(order) - g)]


def centres_and_directions(cameras: Sequence[Camera]) -> tuple[np.ndarray, np.ndarray]:
    """Camera centres ``(N, 3)`` (world units) and unit viewing directions ``(N, 3)`` (the camera +z axis in world
    coordinates; ``viewmat`` is world→camera with OpenCV axes)."""
    vm = np.stack([np.asarray(c.viewmat, np.float64) for c in cameras])
    R, t = vm[:, :3, :3], vm[:, :3, 3]
    centres = -np.einsum("nji,nj->ni", R, t)
    dirs = R[:, 2, :] / np.linalg.norm(R[:, 2, :], axis=1, keepdims=True)
    return centres, dirs


def _nn_scale(dist: np.ndarray, tol: float) -> float:
    """Median over rows of the smallest entry above ``tol`` (the nearest distinct other); 0 when there is none."""
    nearest = np.where(dist > tol, dist, np.inf).min(axis=1)
    nearest = nearest[np.isfinite(nearest)]
    return float(np.median(nearest)) if len(nearest) else 0.0


def pose_distances(cameras: Sequence[Camera]) -> np.ndarray:
    """The pose distance ``d`` ``(N, N)`` of the module docstring (symmetric, zero diagonal, unitless)."""
    c, v = centres_and_directions(cameras)
    dc = np.linalg.norm(c[:, None, :] - c[None, :, :], axis=-1)
    cross = np.linalg.norm(np.cross(v[:, None, :], v[None, :, :]), axis=-1)
    theta = np.arctan2(cross, np.einsum("ik,jk->ij", v, v))  # accurate for small angles, unlike arccos
    s = _nn_scale(dc, 1e-12 * (1.0 + float(np.abs(c).max())))
    s_theta = max(_nn_scale(theta, 1e-12), MIN_ANGLE_SCALE)
    d2 = np.zeros_like(dc)
    if s > 0.0:
        d2 += (dc / s) ** 2
    if float(theta.max()) > 1e-12:
        d2 += (theta / s_theta) ** 2
    d = np.sqrt(d2)
    np.fill_diagonal(d, 0.0)
    return d


def _pick(values: np.ndarray, candidates: np.ndarray, rank: np.ndarray, largest: bool = False) -> int:
    """The candidate with the smallest (``largest``: largest) value; ties within a relative tolerance go to the
    lowest ``rank``."""
    vals = values[candidates]
    best = vals.max() if largest else vals.min()
    tol = _REL_TOL * max(abs(float(best)), 1e-300)
    tied = candidates[np.abs(vals - best) <= tol]
    return int(tied[np.argmin(rank[tied])])


def _greedy_chain(d: np.ndarray, start: int, rank: np.ndarray) -> list[int]:
    n = len(d)
    path, left = [start], np.ones(n, bool)
    left[start] = False
    while left.any():
        nxt = _pick(d[path[-1]], np.flatnonzero(left), rank)
        path.append(nxt)
        left[nxt] = False
    return path


def _length(d: np.ndarray, path: Sequence[int]) -> float:
    return float(sum(d[a, b] for a, b in zip(path[:-1], path[1:])))


def _two_opt(d: np.ndarray, path: list[int], max_passes: int = 100) -> list[int]:
    """Open-path 2-opt: reverse ``path[i+1 … j]`` whenever that shortens the path, until no reversal does.

    A reversal swaps the edges (p_i, p_{i+1}) and (p_j, p_{j+1}) for (p_i, p_j) and (p_{i+1}, p_{j+1}); at an end
    of the path there is only one edge to swap.
    """
    p, n = list(path), len(path)
    scale = float(d.max()) or 1.0
    for _ in range(max_passes):
        improved = False
        for i in range(-1, n - 2):
            for j in range(i + 2 if i >= 0 else 1, n):
                old = (d[p[i], p[i + 1]] if i >= 0 else 0.0) + (d[p[j], p[j + 1]] if j < n - 1 else 0.0)
                new = (d[p[i], p[j]] if i >= 0 else 0.0) + (d[p[i + 1], p[j + 1]] if j < n - 1 else 0.0)
                if old - new > _REL_TOL * scale:
                    p[i + 1 : j + 1] = p[i + 1 : j + 1][::-1]
                    improved = True
        if not improved:
            break
    return p


def pose_path(cameras: Sequence[Camera]) -> list[int]:
    """Indices of ``cameras`` in the order of a short path through their poses (module docstring).

    Depends on the poses and names only: a permutation of ``cameras`` gives the same views in the same order.
    """
    n = len(cameras)
    if n < 2:
        return list(range(n))
    names = [c.name for c in cameras]
    rank = np.argsort(np.argsort(np.array(names, dtype=object), kind="stable"), kind="stable")
    d = pose_distances(cameras)
    # an end of the diameter: the farthest pair (ties: lowest-ranked views)
    far = d.max(axis=1)
    a = _pick(far, np.arange(n), rank, largest=True)
    b = _pick(d[a], np.flatnonzero(np.arange(n) != a), rank, largest=True)
    chains = [_greedy_chain(d, s, rank) for s in sorted((a, b), key=lambda k: rank[k])]
    lengths = [_length(d, ch) for ch in chains]
    path = chains[1] if lengths[1] < lengths[0] * (1 - _REL_TOL) else chains[0]
    path = _two_opt(d, path)
    return path if rank[path[0]] < rank[path[-1]] else path[::-1]


def consistency_pairs(cameras: Sequence[Camera], mode: PairMode, short_gap: int, long_gap: int) -> ViewPairs:
    """The short- and long-range consistency pairs of ``cameras`` (``mode``: ``pose`` or ``index``)."""
    n = len(cameras)
    clipped_gap(n, 1)  # at least 2 views
    if mode == "pose":
        order = pose_path(cameras)
    elif mode == "index":
        order = list(range(n))
    else:
        raise InputError(f"unknown consistency pair mode {mode!r} (pose | index)")
    return ViewPairs(mode, order, path_pairs(order, short_gap), path_pairs(order, long_gap),
                     clipped_gap(n, short_gap), clipped_gap(n, long_gap))


def index_pairs(n: int, short_gap: int, long_gap: int) -> ViewPairs:
    """:class:`ViewPairs` of ``n`` views in list order (no cameras needed)."""
    order = list(range(n))
    return ViewPairs("index", order, path_pairs(order, short_gap), path_pairs(order, long_gap),
                     clipped_gap(n, short_gap), clipped_gap(n, long_gap))
