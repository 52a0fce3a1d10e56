"""One labelled or tracked car as KITTI rows, for the cross-validation and calibration tests."""

from __future__ import annotations

import numpy as np

from lastmile.evaluation.kitti_io import KittiRows


def car_rows(x: float, track_id: int, score: float | list[float], frames: int) -> KittiRows:
    """A car at lateral offset ``x`` m, 15 m ahead, in frames 0 .. frames-1 (``score``: one, or per frame)."""
    n = frames
    return KittiRows(
        frame=np.arange(n, dtype=np.int64),
        track_id=np.full(n, track_id, np.int64),
        obj_type=np.full(n, "Car", dtype=object),
        truncation=np.zeros(n),
        occlusion=np.zeros(n, np.int64),
        alpha_rad=np.zeros(n),
        image_box=np.tile([100.0, 100.0, 200.0, 200.0], (n, 1)),
        camera_box=np.tile([1.5, 1.6, 3.9, x, 1.7, 15.0, -np.pi / 2], (n, 1)),
        score=np.broadcast_to(np.asarray(score, dtype=np.float64), (n,)).copy(),
    )
