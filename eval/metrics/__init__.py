"""Evaluation metrics of stylized 3DGS scenes (SPEC stage 7): content, consistency, FID/KID, ArtFID, speed.

What is comparable to the ABC-GS paper's table and what is a named proxy:

- ``ssim`` — standard Wang et al. SSIM between original and stylized renders: comparable in definition
  (view set, resolution and SSIM implementation details may differ; ``ssim_impl`` says which ran).
- ``short_rmse`` / ``long_rmse`` — masked warp RMSE: comparable in definition; the flow is RAFT (as the
  authors' later code) only where torchvision and its weights are on disk, else OpenCV DIS (provenance says
  which), and the view pairs differ.
- ``short_lpips`` / ``long_lpips`` / ``artfid`` — only when the real LPIPS-alex and ArtFID's art-trained
  Inception ran. Offline they cannot, and the keys are ``*_lpips_proxy_vgg`` / ``artfid_proxy``: proxies on a
  different scale, for comparing runs of this project only.
- ``fid_tf_inception`` / ``kid_tf_inception`` — patch-based FID/KID on the standard TF-FID Inception; not the
  ArtFID FID, and not comparable to whole-image FIDs.
- ``render_fps`` / ``stylize_seconds`` — this machine and backend (recorded), not an RTX 4090.
"""

from importlib import import_module

# Lazy re-exports: importing every metric (and its networks) on `import eval.metrics` would be slow.
# The stage's params model lives in the library (abcgs.eval_params) so that abcgs never imports eval/.
_WHERE = {
    "EvalResult": "evaluate", "evaluate_images": "evaluate", "evaluate_scene": "evaluate",
    "FlowEstimator": "consistency", "backward_warp": "consistency", "fb_consistency_mask": "consistency",
    "view_pairs": "consistency", "SSIM": "content", "PerceptualDistance": "content", "masked_rmse": "content",
    "ssim_wang": "content", "TFInception": "fid", "fid_from_features": "fid", "frechet_distance": "fid", "kid": "fid",
    "mmd2_unbiased": "fid", "artfid_formula": "artfid",
}
__all__ = list(_WHERE)


def __getattr__(name: str):
    if name in _WHERE:
        return getattr(import_module(f"eval.metrics.{_WHERE[name]}"), name)
    raise AttributeError(f"module 'eval.metrics' has no attribute {name!r}")
