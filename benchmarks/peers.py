"""The peers users compare us with, as ground-segmentation adapters; prints their baselines.

    python benchmarks/peers.py                 # F1 and median time of every installed peer
    python benchmarks/peers.py csf smrf        # only these

The adapters live in :mod:`o3d_terrain.evaluation.peers` (so ``o3d-terrain eval segmentation
--method NAME`` can use them too); each has ``name`` and
``segment(positions: (N, 3) float64) -> (N,) bool ground mask``. Their settings (package
defaults; data-dependent parameters only where a peer requires them) are documented there and
in docs/benchmarks.md. Install them with the ``bench`` extra: pip install 'o3d_terrain[bench]'.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from o3d_terrain.evaluation.peers import (  # noqa: E402
    PEERS,
    ClothSimulationFilter,
    PatchworkPP,
    RansacPlane,
    SimpleMorphologicalFilter,
    make_peer,
    peer_status,
)

__all__ = ["PEERS", "ClothSimulationFilter", "PatchworkPP", "RansacPlane",
           "SimpleMorphologicalFilter", "make_peer", "peer_status"]


def main(argv: list[str]) -> int:
    from o3d_terrain.evaluation.datasets import data_root, las_frames, semantic_kitti_frames
    from o3d_terrain.evaluation.segmentation import evaluate_segmentation

    names = argv or list(PEERS)
    status = peer_status()
    root = data_root()
    if root is None:
        print("no ../shared/data folder (set O3D_TERRAIN_DATA); nothing to measure")
        return 1
    for name in names:
        if status.get(name):
            print(f"{name}: n/a ({status[name]})")
            continue
        for label, frames in (("SemanticKITTI", semantic_kitti_frames(root / "kitti_seq00_lidar")),
                              ("LAS tiles", las_frames(root / "las"))):
            report = evaluate_segmentation(frames, name, dataset=label)
            print(report.to_markdown())
            print()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
