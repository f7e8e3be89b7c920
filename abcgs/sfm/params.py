"""The ``reconstruct`` section's schema (:mod:`abcgs.sfm.colmap`).

Schema modules import nothing heavier than pydantic, so that reading ``params.yaml`` does not load the code
it configures (each stage's code dependencies stay its own: ``abcgs/dag.py``).
"""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field

from abcgs.sections import MAX_THREADS, Bound, Bounded

EXHAUSTIVE_MAX_IMAGES = 100
"""``matcher: auto`` matches all pairs up to this many images, sequentially above."""


class ReconstructParams(Bounded, extra="forbid"):
    """Options of the ``reconstruct`` stage (``params.yaml`` section ``reconstruct:``)."""

    min_registered_fraction: float = Field(0.9, ge=0.0, le=1.0, description="fail below this fraction of registered images")
    matcher: Literal["auto", "exhaustive", "sequential"] = Field(
        "auto", description=f"auto = exhaustive up to {EXHAUSTIVE_MAX_IMAGES} images, else sequential"
    )
    sequential_overlap: int = Field(10, ge=1, description="sequential matcher: neighbours matched on each side")
    max_image_size: int = Field(3200, ge=-1, description="SIFT runs on images downscaled to this longest side (-1 = no limit)")
    sift_peak_threshold: float = Field(
        0.02 / 3, gt=0.0, description="SIFT's difference-of-Gaussians peak threshold (COLMAP's default 0.02 / 3); "
        "lower finds more, weaker features: small images (bonsai at 504 x 336 registered all 48 views with 0.002, "
        "docs/MASKS.md)")
    sift_domain_size_pooling: bool = Field(
        False, description="DSP-SIFT: descriptors pooled over several patch sizes (slower to extract; matches better "
        "across changes of viewpoint and scale)")
    mapper_abs_pose_min_inliers: int = Field(
        30, ge=3, description="incremental mapper: least 2-D–3-D inliers to register a view (COLMAP's default 30)")
    mapper_init_min_tri_angle: float = Field(
        16.0, gt=0.0, description="incremental mapper: least triangulation angle (degrees) of the initial pair's "
                                  "points (COLMAP's default 16)")
    camera_model: Literal["SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV"] = "SIMPLE_RADIAL"
    single_camera: Literal["auto"] | bool = Field(
        "auto", description="share intrinsics between all images; auto = when all images have the same size"
    )
    num_threads: int = Field(1, ge=-1, description="COLMAP threads; -1 = all cores (faster, not bit-reproducible)")
    seed: int = Field(0, ge=0, description="seed for COLMAP's RANSAC / mapper / triangulator")
    max_view_size_ratio: float = Field(
        4.0, ge=0, description="preflight fails when a view has more than this many times the pixels of the "
        "capture's median view (a stray full-size photo among resized ones registers badly or makes the fit slow); "
        "0 turns the check off")

    BOUNDS: ClassVar[dict[str, Bound]] = {
        "sequential_overlap": Bound(1, 1000, "neighbours matched on each side (COLMAP: 10)"),
        "max_image_size": Bound(100, 100_000, off=-1, unit="px", why=(
            "the longest side SIFT runs on (COLMAP: 3200); under 100 px SIFT finds too few features, and no image "
            "is wider than 100 000 px (the readers' limit)")),
        "sift_peak_threshold": Bound(0.0, 1.0, "a difference-of-Gaussians peak on images in [0, 1] (COLMAP: "
                                     "0.0067); at 1 no feature is found"),
        "mapper_abs_pose_min_inliers": Bound(3, 10_000, "2-D–3-D inliers to register a view (COLMAP: 30)"),
        "mapper_init_min_tri_angle": Bound(0.0, 90.0, unit="degrees", why="an angle between two viewing rays "
                                           "(COLMAP: 16)"),
        "num_threads": Bound(-1, MAX_THREADS, "COLMAP threads, -1 for all cores"),
        "seed": Bound(0, 2**31 - 1, "COLMAP's seed, a C int"),
        "max_view_size_ratio": Bound(0.0, 10_000.0, "a ratio of pixel counts to the median view; 0 turns the "
                                     "check off"),
    }
