"""Detection-to-track association: a weighted, gated cost and an optimal (Hungarian) or greedy assignment.

aUToTrack's cost (aUToronto 6.3) combines centre distance, size difference, 3D IoU and class
disagreement. Each term is normalised to about [0, 1] so the weights are comparable:

    cost = w_dist * d / gate + w_size * |size_t - size_d|_1 / |size_t + size_d|_1
           + w_iou * (1 - IoU3D) + w_class * (1 - p_track(class of detection))

Gating: a pair is allowed only if the ground-plane centre distance is at most the gate of the
detection's class, and the cost at most ``max_cost``. Forbidden pairs never match, whatever the rest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from lastmile.core.box3d import iou3d_pairs
from lastmile.core.errors import ConfigError

_FORBIDDEN = 1e6


@dataclass(frozen=True, slots=True, kw_only=True)
class AssociationConfig:
    """Weights (dimensionless) and gates of the association cost.

    Attributes:
        w_dist: weight of centre distance divided by the gate.
        w_size: weight of the relative L1 difference of (length, width, height).
        w_iou: weight of 1 - 3D IoU.
        w_class: weight of 1 - the track's probability of the detection's class.
        max_cost: pairs costing more are forbidden.
        method: "hungarian" (scipy linear_sum_assignment) or "greedy" (cheapest pair first).
    """

    w_dist: float = 1.0
    w_size: float = 0.5
    w_iou: float = 1.0
    w_class: float = 1.0
    max_cost: float = 1.9
    method: str = "hungarian"

    def __post_init__(self) -> None:
        for name in ("w_dist", "w_size", "w_iou", "w_class", "max_cost"):
            v = getattr(self, name)
            if not (v >= 0.0 and np.isfinite(v)):
                raise ConfigError(f"AssociationConfig.{name}: expected a finite value >= 0, got {v!r}")
        if self.method not in ("hungarian", "greedy"):
            raise ConfigError(
                f"AssociationConfig.method: expected 'hungarian' or 'greedy', got {self.method!r}"
            )


def association_cost(
    track_boxes: np.ndarray,
    track_class_prob: np.ndarray,
    det_boxes: np.ndarray,
    det_class: np.ndarray,
    det_gate_m: np.ndarray,
    cfg: AssociationConfig,
) -> np.ndarray:
    """Cost matrix (tracks x detections); forbidden pairs hold a large value (>= 1e6).

    Args:
        track_boxes: (T, 7) predicted track boxes.
        track_class_prob: (T, C) class posteriors.
        det_boxes: (D, 7) detected boxes.
        det_class: (D,) class index of each detection.
        det_gate_m: (D,) centre-distance gate of each detection's class.
        cfg: weights and limits.
    """
    t, d = track_boxes.shape[0], det_boxes.shape[0]
    if t == 0 or d == 0:
        return np.zeros((t, d))
    dist = np.hypot(
        track_boxes[:, None, 0] - det_boxes[None, :, 0], track_boxes[:, None, 1] - det_boxes[None, :, 1]
    )
    gate = det_gate_m[None, :]
    allowed = dist <= gate
    cost = cfg.w_dist * dist / np.maximum(gate, 1e-6)
    if cfg.w_size:
        ts, ds = track_boxes[:, None, 3:6], det_boxes[None, :, 3:6]
        cost = cost + cfg.w_size * np.abs(ts - ds).sum(-1) / np.maximum((ts + ds).sum(-1), 1e-6)
    if cfg.w_iou:
        iou = np.zeros((t, d))
        ii, jj = np.nonzero(allowed)
        if ii.size:
            # IoU only for gated pairs: most pairs are far apart.
            iou[ii, jj] = iou3d_pairs(track_boxes[ii], det_boxes[jj])
        cost = cost + cfg.w_iou * (1.0 - iou)
    if cfg.w_class:
        cost = cost + cfg.w_class * (1.0 - track_class_prob[:, det_class])
    allowed &= cost <= cfg.max_cost
    return np.where(allowed, cost, _FORBIDDEN)


def assign(cost: np.ndarray, method: str = "hungarian") -> tuple[np.ndarray, np.ndarray]:
    """Matched (track index, detection index) pairs with an allowed cost.

    Hungarian minimises the summed cost over allowed pairs; greedy takes the cheapest pair first.
    """
    if cost.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    if method == "hungarian":
        r, c = linear_sum_assignment(cost)
    else:
        flat = np.argsort(cost, axis=None, kind="stable")
        flat = flat[cost.ravel()[flat] < _FORBIDDEN]
        rr, cc = np.unravel_index(flat, cost.shape)
        used_r = np.zeros(cost.shape[0], bool)
        used_c = np.zeros(cost.shape[1], bool)
        keep_r, keep_c = [], []
        for i, j in zip(rr.tolist(), cc.tolist(), strict=True):
            if not used_r[i] and not used_c[j]:
                used_r[i] = used_c[j] = True
                keep_r.append(i)
                keep_c.append(j)
        r, c = np.array(keep_r, np.int64), np.array(keep_c, np.int64)
    ok = cost[r, c] < _FORBIDDEN
    return r[ok].astype(np.int64), c[ok].astype(np.int64)
