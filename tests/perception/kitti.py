"""KITTI object-frame helpers for tests and benchmarks: velodyne clouds and labels in the velodyne frame."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

KITTI_DIR = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "kitti_object"
VELODYNE_HEIGHT_M = 1.73  # KITTI's HDL-64E above the road: adding it puts flat ground at z = 0
OBJECT_CLASSES = ("Car", "Pedestrian", "Cyclist")


@dataclass(frozen=True)
class KittiLabel:
    kind: str
    h: float
    w: float
    l: float  # noqa: E741 - KITTI's own name for the box length
    xyz_rect: np.ndarray  # bottom centre, rectified camera frame
    ry: float


@dataclass(frozen=True)
class KittiFrame:
    name: str
    velo: np.ndarray  # (N, 4) float32 x y z reflectance, velodyne frame
    labels: tuple[KittiLabel, ...]
    R0: np.ndarray  # (3, 3)
    Tr: np.ndarray  # (3, 4) velo -> cam

    def rect_from_velo(self, xyz: np.ndarray) -> np.ndarray:
        return (xyz @ self.Tr[:, :3].T + self.Tr[:, 3]) @ self.R0.T

    def in_box(self, label: KittiLabel, xyz_velo: np.ndarray, bottom_margin_m: float = 0.0) -> np.ndarray:
        """(N,) bool: points inside the label's 3D box (above its bottom by ``bottom_margin_m``)."""
        d = self.rect_from_velo(xyz_velo) - label.xyz_rect
        c, s = np.cos(label.ry), np.sin(label.ry)
        lx = c * d[:, 0] - s * d[:, 2]  # R_y(ry)^T applied to the offset
        lz = s * d[:, 0] + c * d[:, 2]
        ly = d[:, 1]  # y down: the box spans [-h, 0] above its bottom centre
        return (
            (np.abs(lx) <= label.l / 2)
            & (np.abs(lz) <= label.w / 2)
            & (ly <= -bottom_margin_m)
            & (ly >= -label.h)
        )

    def centre_velo(self, label: KittiLabel) -> np.ndarray:
        c_rect = label.xyz_rect - np.array([0.0, label.h / 2, 0.0])
        cam = np.linalg.solve(self.R0, c_rect)
        return (cam - self.Tr[:, 3]) @ self.Tr[:, :3]  # R^T (cam - t)


def frame_names() -> list[str]:
    if not (KITTI_DIR / "velodyne").is_dir():
        return []
    return sorted(p.stem for p in (KITTI_DIR / "velodyne").glob("*.bin"))


def load_frame(name: str) -> KittiFrame:
    velo = np.fromfile(KITTI_DIR / "velodyne" / f"{name}.bin", dtype=np.float32).reshape(-1, 4)
    calib = {}
    for line in (KITTI_DIR / "calib" / f"{name}.txt").read_text().splitlines():
        if ":" in line:
            k, v = line.split(":", 1)
            calib[k.strip()] = np.array([float(x) for x in v.split()])
    labels = []
    for line in (KITTI_DIR / "label_2" / f"{name}.txt").read_text().splitlines():
        f = line.split()
        if not f or f[0] == "DontCare":
            continue
        h, w, l_, x, y, z, ry = (float(v) for v in f[8:15])
        labels.append(KittiLabel(f[0], h, w, l_, np.array([x, y, z]), ry))
    return KittiFrame(
        name, velo, tuple(labels), calib["R0_rect"].reshape(3, 3), calib["Tr_velo_to_cam"].reshape(3, 4)
    )
