"""Trajectory errors against a reference: APE statistics as evo computes them, along/cross-track, NEES."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from lastmile.core.errors import MessageError

CHI2_2DOF_95 = 5.991464547107979
"""95 % quantile of the chi-square distribution with 2 degrees of freedom (horizontal NEES bound)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class ApeStatistics:
    """Absolute position error statistics, m: evo's ``evo_ape`` (translation part, no alignment)."""

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    sse: float
    count: int

    def as_dict(self) -> dict[str, float | int]:
        return asdict(self)


def position_errors_m(estimate_xy: np.ndarray, reference_xy: np.ndarray) -> np.ndarray:
    """(N,) Euclidean distances between matched (N, 2) or (N, 3) positions, m."""
    est, ref = np.asarray(estimate_xy, dtype=float), np.asarray(reference_xy, dtype=float)
    if est.shape != ref.shape or est.ndim != 2 or est.shape[1] not in (2, 3):
        raise MessageError(
            f"position_errors_m: expected two (N, 2|3) arrays, got {est.shape} and {ref.shape}"
        )
    return np.linalg.norm(est - ref, axis=1)


def ape_statistics(errors_m: np.ndarray) -> ApeStatistics:
    """Statistics of absolute position errors, with evo's definitions (``std`` is the population one)."""
    e = np.asarray(errors_m, dtype=float)
    if e.ndim != 1 or e.size == 0 or not np.isfinite(e).all():
        raise MessageError(f"ape_statistics: expected a non-empty finite (N,) array, got shape {e.shape}")
    return ApeStatistics(
        rmse=float(np.sqrt(np.mean(e**2))),
        mean=float(np.mean(e)),
        median=float(np.median(e)),
        std=float(np.std(e)),
        min=float(np.min(e)),
        max=float(np.max(e)),
        sse=float(np.sum(e**2)),
        count=int(e.size),
    )


def along_cross_track_m(error_xy: np.ndarray, heading_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split (N, 2) errors (estimate - reference) into longitudinal (along ``heading``) and lateral (left).

    Returns:
        (longitudinal, lateral), each (N,), m.
    """
    err = np.asarray(error_xy, dtype=float)
    c, s = np.cos(heading_rad), np.sin(heading_rad)
    return err[:, 0] * c + err[:, 1] * s, -err[:, 0] * s + err[:, 1] * c


def nees_2d(error_xy: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """(N,) normalised estimation error squared e^T C^-1 e for (N, 2) errors and (N, 2, 2) covariances."""
    err = np.asarray(error_xy, dtype=float)
    cov = np.asarray(covariance, dtype=float)
    if cov.shape != (err.shape[0], 2, 2):
        raise MessageError(f"nees_2d: expected covariances of shape ({err.shape[0]}, 2, 2), got {cov.shape}")
    solved = np.linalg.solve(cov, err[:, :, None])[:, :, 0]
    return np.einsum("ij,ij->i", err, solved)
