"""The style-loss settings (``stylize.fast``) and the names of the style losses (:mod:`abcgs.losses`).

Schema modules import nothing heavier than pydantic, so that reading ``params.yaml`` does not load the code
it configures (each stage's code dependencies stay its own: ``abcgs/dag.py``).
"""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import ConfigDict, Field

from abcgs.features.params import DEFAULT_MAX_BLOCK_ELEMS
from abcgs.sections import Bound, Bounded
from abcgs.types import CandidateProducts, KnnSearch

CosineAxis = Literal["pixel", "channel"]


SMALL_GROUP_RATIO = 1.25
"""Groups with ``N_r < SMALL_GROUP_RATIO · C`` features run FAST's algebra in float64 (module docstring, "Small
groups")."""


class FastParams(Bounded):
    """Knobs of the FAST loss."""

    model_config = ConfigDict(extra="forbid")

    cosine: CosineAxis = "pixel"
    """Axis of the cosine between ``F_r`` and ``F_rs``: ``pixel`` (per feature vector, across channels) or
    ``channel`` (per channel, across the group's pixels: the authors' code). See the module docstring."""

    k: int = Field(5, ge=1)
    """Neighbours per feature in each direction."""
    eps: float = Field(1e-12, ge=0.0)
    """Ridge added to ``F_r D_r F_rᵀ`` before solving (the authors' value)."""
    max_block_elems: int = Field(DEFAULT_MAX_BLOCK_ELEMS, ge=1)
    """Largest number of similarities held at once (tile size of the N_r × N_s similarity)."""
    knn_search: KnnSearch = "auto"
    """Neighbour search: ``exact`` (float32), ``bf16`` (certified: the same neighbours from a bfloat16 product and
    exact re-ranking) or ``auto`` (bf16 on CPUs with native bf16 for large searches); see :mod:`abcgs.features.knn`.
    A runtime knob: it does not change the result (up to ties within float32 rounding)."""
    solve_dtype: Literal["float64", "float32"] = "float64"
    """Dtype of the C × C solve of a group of at least ``SMALL_GROUP_RATIO · C`` features; smaller groups run their
    whole algebra in float64 whatever this says (module docstring, "Small groups")."""
    projection_rank: int = Field(128, ge=0)
    """0: the exact neighbour search (``knn_search`` says how). ``r > 0``: the approximate search for CPU searches of at
    least ``projection_min_similarities`` (on CUDA the exact search runs) — candidates from the features projected onto
    the painting's ``r`` principal feature directions, re-ranked by their exact similarities
    (:class:`abcgs.features.knn.Projection`); used by FAST, NNFM and KNNFM. Its recall by rank and candidates, and
    what it changes in a whole run: docs/SCALING.md "The neighbour search of FAST and NNFM"
    (``python -m eval run knn_recall``); its time: ``docs/measurements/settings.yaml``,
    ``knn_projected_search_time``."""
    projection_candidates: int = Field(16, ge=1)
    """Candidates per feature and direction of the approximate search (at least ``k``)."""
    projection_min_similarities: int = Field(2**22, ge=0)
    """The approximate search runs for ``N_r · N_s`` at least this (fern: 2852 × 6528 = 18.6 M); smaller searches (the
    embedded tiny scene's) are cheap exactly and stay exact."""
    projection_products: CandidateProducts = "auto"
    """The projected products that pick the candidates (:attr:`abcgs.features.knn.Projection.products`): ``float32``,
    ``bfloat16`` or ``auto`` (bfloat16 where the CPU kernels have AVX512-BF16). The candidates are re-ranked exactly
    either way; docs/SCALING.md has the measured recall and time of both."""

    BOUNDS: ClassVar[dict[str, Bound]] = {
        "k": Bound(1, 256, "neighbours per feature (the authors: 5); a group's features are a few thousand"),
        "eps": Bound(0.0, 1.0, "a ridge added to F_r D_r F_rᵀ (the authors: 1e-12); at 1 it outweighs the features"),
        "max_block_elems": Bound(1, 2**31, "similarities held at once: 2**31 float32 are 8 GiB a tile"),
        "projection_rank": Bound(0, 512, "principal feature directions; VGG-16's widest taps have 512 channels"),
        "projection_candidates": Bound(1, 4096, "candidates per feature and direction; more than a group's "
                                       "features search exactly"),
        "projection_min_similarities": Bound(0, 2**62, "a count of similarities N_r x N_s"),
    }
