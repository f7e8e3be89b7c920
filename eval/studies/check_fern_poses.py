"""Check a COLMAP reconstruction of LLFF fern against LLFF's own poses (``poses_bounds.npy``).

Usage: ``python -m eval run check_fern_poses [--scene ../shared/data/scenes/fern] [--colmap out/fern/colmap]``

If ``--colmap`` holds no scene yet (``scene.json``), the scene is reconstructed into it first (or into a
temporary folder when ``--colmap`` is not given). Camera centres are compared after a similarity
(Umeyama) alignment; the script prints the RMS residual relative to the scene extent (RMS distance
of the LLFF centres from their centroid) and exits non-zero above ``--max-rel``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from abcgs.io.images import list_images
from abcgs.layout import ColmapDir
from abcgs.sfm.align import alignment_residual
from abcgs.sfm.model import read_scene
from abcgs.sfm.params import ReconstructParams
from abcgs.sources.llff import llff_camera_centres
from abcgs.sources.params import SceneParams
from abcgs.sources.reconstruct import reconstruct_scene

DEFAULT_SCENE = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "scenes" / "fern"


@dataclass
class PoseCheck:
    """Result of :func:`check_poses`: residuals in LLFF units and relative to the LLFF extent."""

    registered: int
    total: int
    rms: float
    relative: float
    scale: float


def check_poses(scene: Path, colmap_dir: Path, params: ReconstructParams | None = None) -> PoseCheck:
    """Reconstruct ``scene`` into ``colmap_dir`` unless a scene is there, then compare camera centres."""
    if not ColmapDir(colmap_dir).scene.is_file():
        reconstruct_scene(SceneParams.at(scene, "photos"), colmap_dir, params)
    names = [p.name for p in list_images(scene / "images")]
    llff = dict(zip(names, llff_camera_centres(scene / "poses_bounds.npy"), strict=True))
    data = read_scene(colmap_dir)
    src = np.array([c.center for c in data.cameras])
    dst = np.array([llff[c.name] for c in data.cameras])
    rms, rel, sim = alignment_residual(src, dst)
    return PoseCheck(len(data.cameras), len(names), rms, rel, sim.scale)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", type=Path, default=DEFAULT_SCENE, help="LLFF scene with images/ and poses_bounds.npy")
    ap.add_argument("--colmap", type=Path, default=None, help="existing reconstruct output (or where to write one)")
    ap.add_argument("--max-rel", type=float, default=0.05, help="fail above this relative RMS residual")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="fern-check-") as tmp:
        res = check_poses(args.scene, args.colmap or Path(tmp) / "colmap")
    print(
        f"{res.registered}/{res.total} registered; camera-centre RMS after similarity alignment "
        f"{res.rms:.4g} (LLFF units) = {res.relative:.2%} of the scene extent; {time.perf_counter() - t0:.1f} s"
    )
    ok = res.registered == res.total and res.relative <= args.max_rel
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
