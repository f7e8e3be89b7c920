"""Evaluation of stylized 3DGS scenes: content, consistency, style distances, speed.

What is comparable to the ABC-GS paper's table and what is a named proxy (docs/METRICS.md):

- ``ssim`` (headline ``content_ssim``) — standard Wang et al. SSIM between original and stylized renders:
  comparable in definition (view set, resolution and SSIM implementation details may differ; ``ssim_impl`` says
  which ran).
- ``short_rmse`` / ``long_rmse`` — masked warp RMSE: comparable in definition; the flow is RAFT only where
  torchvision and its weights are on disk, else OpenCV DIS (provenance says which), and the view pairs differ.
- ``short_lpips`` / ``long_lpips`` / ``artfid`` — only when the real LPIPS-alex and ArtFID's art-trained
  Inception ran. Offline they cannot, and the keys are ``*_lpips_proxy_vgg`` / ``artfid_proxy``: proxies on a
  different scale, for comparing runs of this project only.
- ``fid_tf_inception`` / ``kid_tf_inception`` — patch-based FID/KID on the standard TF-FID Inception; not the
  ArtFID FID, and not comparable to whole-image FIDs.
- ``render_fps`` / ``stylize_seconds`` — this machine and backend (recorded), not an RTX 4090.

Modules: :mod:`~abcgs.evaluation.content`, :mod:`~abcgs.evaluation.consistency`, :mod:`~abcgs.evaluation.fid`,
:mod:`~abcgs.evaluation.artfid`, :mod:`~abcgs.evaluation.style_distance`, the per-scene
:mod:`~abcgs.evaluation.reference`, and :mod:`~abcgs.evaluation.evaluate`, which runs them all for the stage.
"""
