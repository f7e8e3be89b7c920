"""Every path under ``out/``: what each stage writes and where the next one finds it.

Per scene ``S``, colour match ``M`` (``colormatches.M``) and experiment ``E``::

    out/preflight.json, out/preflight_report.json, out/label_use/S.json      preflight
    out/styles/P.png, out/styles/P.labels.png                                styles, style_masks (painting P)
    out/S/colmap/{sparse,images,masks,scene.json}, out/S/reconstruct.json    reconstruct
    out/S/gs/{point_cloud.ply, metrics.json, history.csv, …}, fit_metrics.json  fit
    out/S/masks/{gaussian_labels.npy, views/*.png, overlay.png, masks.json}  masks
    out/S/reference/                                                         reference
    out/S/colormatch/M/{point_cloud.ply, fitted_rows.npy, colormatch.json, recolored.png}  colormatch (for the E of M)
    out/S/point_cloud.spz                                                    export_scene
    out/E/stylize/{point_cloud.ply, fitted_rows.npy, renders/, grid.png, turntable.mp4}, stylize.json, …  stylize
    out/E/{eval.json, metrics.json, eval_views.csv, eval_consistency.png}    evaluate
    out/E/point_cloud.spz, out/E/returned/                                   export

The classes take a folder and name the files in it; :func:`scene` and :func:`experiment` give a scene's and an
experiment's folders. Called with a template name (``scene("{item.scene}")``) they give the path templates that
the stage specs (``stages/*.py``) pass on ``dvc.yaml``'s command lines, so the pipeline definition and the code
name each path in this one place.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from abcgs.io.metrics import info_path

OUT = Path("out")
"""The pipeline's output root (relative to the repository root)."""
PREFLIGHT_STAMP = OUT / "preflight.json"
"""The preflight stage's stamp: every other stage depends on it (its content never changes)."""
PREFLIGHT_REPORT = OUT / "preflight_report.json"
"""The preflight stage's warnings."""
LABEL_USE = OUT / "label_use"
"""Per scene ``S``, ``S.json``: whether a colour match reads the scene's content labels (:func:`label_use`)."""


def label_use(scene: str, out: Path = OUT) -> Path:
    """``out/label_use/<scene>.json``, written by the preflight stage: ``{"content_labels_read": bool}``, true when
    a colour match of the scene is compositional or semantic. The ``masks`` stage of the scene depends on this
    file alone, not on the colour matches, so it re-runs only when that answer changes."""
    return Path(out) / LABEL_USE.relative_to(OUT) / f"{scene}.json"
STYLES = OUT / "styles"
"""The paintings of ``data.styles`` and the region maps of ``data.style_masks``, as :class:`StylesDir` names them."""


@dataclass(frozen=True)
class StylesDir:
    """The paintings (``<key>.png``) and their region maps (``<key>.labels.png``), each copied here by its own stage
    (``styles``, ``style_masks``): the stages that read a painting depend on this folder, so DVC re-runs them when a
    painting's content changes, where the params hold only its path."""

    root: Path

    def painting(self, key: str) -> Path:
        return self.root / f"{key}.png"

    def labels(self, key: str) -> Path:
        return self.root / f"{key}.labels.png"

    def paintings(self, keys: Iterable[str]) -> dict[str, str]:
        """``{key: path}`` of the paintings ``keys`` (``data.styles``' keys), as the matching groups take them."""
        return {k: str(self.painting(k)) for k in keys}

    def label_maps(self, keys: Iterable[str]) -> dict[str, str]:
        """``{key: path}`` of the region maps ``keys`` (``data.style_masks``' keys)."""
        return {k: str(self.labels(k)) for k in keys}


def styles(out: str | Path = OUT) -> StylesDir:
    """The paintings' folder under the output root ``out``."""
    return StylesDir(Path(out) / STYLES.relative_to(OUT))


@dataclass(frozen=True)
class ColmapDir:
    """A COLMAP layout (the reconstruct stage's output): ``sparse/`` (cameras, images, points3D), ``images/``
    (undistorted), ``scene.json`` (the rest of the scene) and, when the scene has them, ``alpha/`` and ``masks/``."""

    root: Path

    @property
    def sparse(self) -> Path:
        return self.root / "sparse"

    @property
    def images(self) -> Path:
        return self.root / "images"

    @property
    def masks(self) -> Path:
        return self.root / "masks"

    @property
    def scene(self) -> Path:
        """The rest of the scene beside its model: format, frame, background, splat, per-view files (JSON,
        :func:`abcgs.sfm.model.write_scene`; read with :func:`abcgs.sfm.model.read_scene`)."""
        return self.root / "scene.json"


@dataclass(frozen=True)
class FitDir:
    """The fit stage's folder: the fitted (or imported) 3DGS and its records."""

    root: Path

    @property
    def ply(self) -> Path:
        """The fitted Gaussians, INRIA PLY layout."""
        return self.root / "point_cloud.ply"

    @property
    def record(self) -> Path:
        """Held-out metrics and provenance (JSON)."""
        return self.root / "metrics.json"

    @property
    def history(self) -> Path:
        """Per-step training PSNR/loss (CSV, a DVC plot)."""
        return self.root / "history.csv"

    @property
    def heldout_grid(self) -> Path:
        return self.root / "heldout_grid.png"

    @property
    def splat_source(self) -> Path:
        """Where the splat came from (a fit, or an imported file and its format/frame): what export gives back."""
        return self.root / "splat_source.json"


@dataclass(frozen=True)
class MasksDir:
    """The masks stage's folder: content labels per Gaussian and per view."""

    root: Path

    @property
    def gaussian_labels(self) -> Path:
        """``(N,) uint8`` label per Gaussian (numpy)."""
        return self.root / "gaussian_labels.npy"

    @property
    def views(self) -> Path:
        """One label PNG per view, named like the view's image."""
        return self.root / "views"

    @property
    def overlay(self) -> Path:
        return self.root / "overlay.png"

    @property
    def record(self) -> Path:
        """Label names, per-view unlabelled shares, warnings (JSON)."""
        return self.root / "masks.json"


@dataclass(frozen=True)
class ColorMatchDir:
    """A colour match's folder (shared by every experiment naming it)."""

    root: Path

    @property
    def ply(self) -> Path:
        return self.root / "point_cloud.ply"

    @property
    def fitted_rows(self) -> Path:
        """``(N,)`` int64: each colour-matched Gaussian's row in the fitted scene (``abcgs.gaussians.FITTED_ROW``)."""
        return self.root / "fitted_rows.npy"

    @property
    def record(self) -> Path:
        return self.root / "colormatch.json"

    @property
    def recolored(self) -> Path:
        return self.root / "recolored.png"


@dataclass(frozen=True)
class StylizeDir:
    """The stylize stage's folder: the stylized 3DGS and what is looked at."""

    root: Path

    @property
    def ply(self) -> Path:
        return self.root / "point_cloud.ply"

    @property
    def fitted_rows(self) -> Path:
        """``(N,)`` int64: each stylized Gaussian's row in the fitted scene (its colour match's ``fitted_rows.npy``)."""
        return self.root / "fitted_rows.npy"

    @property
    def renders(self) -> Path:
        """One PNG per view, named like the view's image."""
        return self.root / "renders"

    @property
    def grid(self) -> Path:
        return self.root / "grid.png"

    @property
    def turntable(self) -> Path:
        return self.root / "turntable.mp4"


@dataclass(frozen=True)
class SceneOut:
    """``out/<scene>/``: everything the per-scene stages write."""

    root: Path

    @property
    def colmap(self) -> ColmapDir:
        return ColmapDir(self.root / "colmap")

    @property
    def reconstruct_record(self) -> Path:
        return self.root / "reconstruct.json"

    @property
    def fit(self) -> FitDir:
        return FitDir(self.root / "gs")

    @property
    def fit_headline(self) -> Path:
        """The fit's headline metrics (a DVC metric)."""
        return self.root / "fit_metrics.json"

    @property
    def masks(self) -> MasksDir:
        return MasksDir(self.root / "masks")

    @property
    def reference(self) -> Path:
        """The evaluation's reference: the original scene's renders and optical flows."""
        return self.root / "reference"

    def colormatch(self, name: str) -> ColorMatchDir:
        return ColorMatchDir(self.root / "colormatch" / name)

    @property
    def spz(self) -> Path:
        return self.root / "point_cloud.spz"


@dataclass(frozen=True)
class ExperimentOut:
    """``out/<experiment>/``: what the stylize, evaluate and export stages write for one experiment."""

    root: Path

    @property
    def stylize(self) -> StylizeDir:
        return StylizeDir(self.root / "stylize")

    @property
    def stylize_record(self) -> Path:
        """The run's record (JSON); its provenance goes beside it (:func:`abcgs.io.metrics.info_path`)."""
        return self.root / "stylize.json"

    @property
    def stylize_history(self) -> Path:
        """Per-step loss terms (CSV, a DVC plot)."""
        return self.root / "stylize_history.csv"

    @property
    def eval_record(self) -> Path:
        """Every metric (JSON); its provenance goes beside it (:func:`abcgs.io.metrics.info_path`)."""
        return self.root / "eval.json"

    @property
    def eval_headline(self) -> Path:
        """The headline metrics (a DVC metric)."""
        return self.root / "metrics.json"

    @property
    def eval_views(self) -> Path:
        """Per-view consistency (CSV, a DVC plot)."""
        return self.root / "eval_views.csv"

    @property
    def eval_consistency(self) -> Path:
        return self.root / "eval_consistency.png"

    @property
    def spz(self) -> Path:
        return self.root / "point_cloud.spz"

    @property
    def returned(self) -> Path:
        """The stylized scene in its source's format and frame."""
        return self.root / "returned"


def scene(name: str, out: Path = OUT) -> SceneOut:
    """``out/<name>/``."""
    return SceneOut(out / name)


def experiment(name: str, out: Path = OUT) -> ExperimentOut:
    """``out/<name>/``."""
    return ExperimentOut(out / name)


def report_inputs(params) -> list[str]:
    """The outputs the ``report`` stage reads for the experiments and paintings of ``params`` (validated
    ``params.yaml``), one by one: its ``dvc.yaml`` deps besides the preflight stamp. ``dvc.yaml`` lists them
    (:mod:`abcgs.dag` fills them in from ``params.yaml``), and the ``report`` stage refuses to run from a ``dvc.yaml``
    that lacks some (:func:`abcgs.preflight.check_report_inputs`)."""
    paths: list[Path] = [PREFLIGHT_REPORT]
    paths += [Path(p) for p in styles().paintings(params.data.styles).values()]
    scenes: list[str] = []
    for name, exp in params.experiments.items():
        d = experiment(name)
        paths += [d.stylize_record, info_path(d.stylize_record), d.eval_record, info_path(d.eval_record),
                  d.eval_consistency, d.stylize.root]
        if exp.scene not in scenes:
            scenes.append(exp.scene)
    for name in scenes:  # the photos and cameras, the viewer's original splat and labels, the run's warnings
        s = scene(name)
        paths += [s.colmap.root, s.reconstruct_record, s.fit.ply, s.masks.root]
    return [p.as_posix() for p in paths]
