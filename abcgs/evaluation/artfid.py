"""ArtFID (Wright & Ommer 2022): ArtFID = (1 + LPIPS_content) × (1 + FID(style, stylized)).

The official metric (package ``art-fid``) has two fixed components:

- LPIPS-alex (v0.1, images in [−1, 1]) between each content image and its stylization;
- FID on 2048-d pool features of an Inception-v3 trained on art (``art_inception.pth``, Hugging Face
  ``matthias-wright/art_inception``), between the style images and the stylized images.

Neither component is obtainable offline on this project's machines (no torchvision backbone for LPIPS, no
Hugging Face access). So:

- ``artfid`` is written ONLY when both official components ran: the ``lpips`` package with its AlexNet
  backbone, and an art-Inception given in ``evaluate.art_inception_path`` (or found as
  ``<torch hub dir>/checkpoints/art_inception_torchscript.pt``) as a TorchScript module taking NCHW RGB in
  [0, 1] at 299×299 and returning (N, 2048) — export it once from ``art-fid`` where that package runs
  (it pins numpy < 2 and needs torchvision, so it is not a dependency here).
- otherwise ``artfid_proxy`` = (1 + content distance) × (1 + fid_tf_inception), with both components named
  in ``artfid_components``. Its value is on a different scale from the paper's ArtFID (different FID network,
  patch-based FID at small n, uncalibrated VGG distance) and must not be compared with it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from abcgs.errors import InputError
from abcgs.evaluation.content import ContentScores
from abcgs.evaluation.fid import INCEPTION_SIZE, FidKid, _sha, fid_from_features

ART_INCEPTION_HUB_FILE = "art_inception_torchscript.pt"


def artfid_formula(content_distance: float, fid: float) -> float:
    """(1 + content distance) × (1 + FID) — the ArtFID combination (lower is better, ≥ 1)."""
    return (1.0 + float(content_distance)) * (1.0 + float(fid))


def find_art_inception(path: str | None) -> tuple[Path | None, str]:
    """The art-Inception TorchScript file to use, or None with the reason."""
    if path is not None:
        p = Path(path).expanduser()
        if not p.is_file():
            raise InputError(f"evaluate.art_inception_path {p} does not exist")
        return p, "evaluate.art_inception_path"
    p = Path(torch.hub.get_dir()) / "checkpoints" / ART_INCEPTION_HUB_FILE
    if p.is_file():
        return p, "torch hub cache"
    return None, ("ArtFID's art-trained Inception is not available offline (Hugging Face matthias-wright/art_inception); "
                  "set evaluate.art_inception_path to a TorchScript export")


class ArtInception:
    """User-provided TorchScript art-Inception: NCHW RGB [0, 1] at 299×299 → (N, 2048)."""

    def __init__(self, path: Path, batch: int = 16, device: torch.device | str = "cpu") -> None:
        self.device = torch.device(device)
        try:
            self.model = torch.jit.load(str(path), map_location=self.device).eval()
        except Exception as exc:  # noqa: BLE001  (state dicts, pickles, corrupt files)
            raise InputError(
                f"{path} is not a TorchScript module ({type(exc).__name__}); a plain art_inception.pth state dict needs "
                "art-fid's Inception definition — export the network with torch.jit.trace where art-fid runs"
            ) from None
        self.path, self.batch = Path(path), batch

    @torch.no_grad()
    def features(self, patches: np.ndarray) -> np.ndarray:
        out = []
        for k in range(0, len(patches), self.batch):
            x = torch.from_numpy(np.ascontiguousarray(patches[k : k + self.batch], dtype=np.float32)).permute(0, 3, 1, 2).to(self.device)
            x = F.interpolate(x, size=(INCEPTION_SIZE, INCEPTION_SIZE), mode="bilinear", align_corners=False)
            out.append(self.model(x.clamp(0, 1)).double().reshape(x.shape[0], -1).numpy(force=True))
        return np.concatenate(out)

    def provenance(self) -> dict:
        return {"network": "art-trained Inception-v3 (ArtFID), TorchScript export", "path": str(self.path),
                "sha256": _sha(str(self.path))}


@dataclass(frozen=True)
class ArtFID:
    """ArtFID = (1 + content distance) × (1 + style FID), official or the named proxy (module docstring)."""

    value: float | None
    """The combination, >= 1, lower is better; None when ``evaluate.fid`` is false."""
    official: bool
    """True: both official components ran (record key ``artfid``); False: the proxy (``artfid_proxy``)."""
    content_name: str
    """The content distance used: ``lpips`` or ``lpips_proxy_vgg``."""
    content_value: float
    """Its mean over the views."""
    style_name: str
    """The FID used: ``fid_art_inception`` (official) or ``fid_tf_inception``."""
    style_value: float | None
    """That FID between the style and the stylized patches; None when not computed."""
    style_network: dict | None
    """:meth:`ArtInception.provenance` when the art-trained Inception ran, else None."""
    note: str
    """Why the value is official or a proxy (recorded under ``artfid_components``)."""


def artfid(content: ContentScores, fid: FidKid, perceptual_note: str, art_inception_path: str | None, *,
           batch: int = 16, device: torch.device | str = "cpu") -> ArtFID:
    """ArtFID when real LPIPS ran and an art-Inception is found (:func:`find_art_inception`), on the same random
    patches as ``fid``; else the proxy with ``fid``'s TF-Inception FID. ``perceptual_note``: why the perceptual
    distance is what it is (:attr:`~abcgs.evaluation.content.PerceptualDistance.note`)."""
    art_path, art_why = find_art_inception(art_inception_path)
    name, mean = content.perceptual_name, content.perceptual_mean
    if fid.fid is None:
        return ArtFID(None, False, name, mean, "fid_tf_inception", None, None, "not computed: evaluate.fid is false")
    if art_path is not None and name == "lpips":
        art = ArtInception(art_path, batch, device)
        fid_art = fid_from_features(art.features(fid.style_patches), art.features(fid.stylized_patches))
        return ArtFID(artfid_formula(mean, fid_art), True, name, mean, "fid_art_inception", fid_art, art.provenance(),
                      "official components (LPIPS-alex, art-trained Inception); FID on the same random patches as "
                      "fid_tf_inception")
    reasons = [r for r in ((None if name == "lpips" else f"content distance is {name}: {perceptual_note}"),
                           (None if art_path is not None else art_why)) if r]
    return ArtFID(artfid_formula(mean, fid.fid), False, name, mean, "fid_tf_inception", fid.fid, None,
                  "proxy, NOT comparable to the paper's ArtFID: " + "; ".join(reasons))
