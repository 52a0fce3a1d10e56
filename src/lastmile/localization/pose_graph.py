"""A planar pose graph: absolute pose priors and relative-pose edges, solved by sparse least squares.

The map builder's frames each have a recorded pose (the vehicle's localization: an absolute prior
with its covariance) and a registration to the frames placed before them (a relative pose between
two frames with the registration's covariance). Registering frame after frame to what is already
placed anchors the whole map on the first frame's error; solving all priors and edges together
spreads the absolute information over every frame, and keeps the registrations' local consistency.
SciPy's trust-region least squares with the Jacobian's sparsity pattern (each residual touches one
or two poses) solves a few thousand poses in well under a second.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix


@dataclass(frozen=True, slots=True, kw_only=True)
class RelativeEdge:
    """Pose ``i`` seen from pose ``j``: ``z`` = (x, y, yaw) of i in j's frame, with its covariance."""

    i: int
    j: int
    z: np.ndarray
    covariance: np.ndarray


def relative(pose_i: np.ndarray, pose_j: np.ndarray) -> np.ndarray:
    """(x, y, yaw) of planar pose i in the frame of planar pose j."""
    c, s = math.cos(pose_j[2]), math.sin(pose_j[2])
    dx, dy = pose_i[0] - pose_j[0], pose_i[1] - pose_j[1]
    return np.array([c * dx + s * dy, -s * dx + c * dy, math.remainder(pose_i[2] - pose_j[2], math.tau)])


def _sqrt_info(cov: np.ndarray) -> np.ndarray:
    """L with L^T L = cov^-1 (whitening)."""
    return np.linalg.cholesky(np.linalg.inv(cov)).T


def optimise(
    initial: np.ndarray, priors: np.ndarray, prior_covs: np.ndarray, edges: list[RelativeEdge]
) -> np.ndarray:
    """The poses minimising the whitened prior and edge residuals.

    Args:
        initial: (N, 3) starting poses (x, y, yaw).
        priors: (N, 3) absolute pose measurements.
        prior_covs: (N, 3, 3) their covariances.
        edges: relative-pose measurements.

    Returns:
        (N, 3) optimised poses.
    """
    n = len(initial)
    if n == 0:
        return initial.copy()
    prior_l = np.array([_sqrt_info(c) for c in prior_covs])
    edge_l = [_sqrt_info(e.covariance) for e in edges]

    def residuals(flat: np.ndarray) -> np.ndarray:
        x = flat.reshape(n, 3)
        d = x - priors
        d[:, 2] = np.remainder(d[:, 2] + math.pi, math.tau) - math.pi
        out = [np.einsum("nij,nj->ni", prior_l, d).ravel()]
        for e, el in zip(edges, edge_l, strict=True):
            r = relative(x[e.i], x[e.j]) - e.z
            r[2] = math.remainder(r[2], math.tau)
            out.append(el @ r)
        return np.concatenate(out)

    sparsity = lil_matrix((3 * n + 3 * len(edges), 3 * n), dtype=np.int8)
    for k in range(n):
        sparsity[3 * k : 3 * k + 3, 3 * k : 3 * k + 3] = 1
    for m, e in enumerate(edges):
        row = 3 * n + 3 * m
        sparsity[row : row + 3, 3 * e.i : 3 * e.i + 3] = 1
        sparsity[row : row + 3, 3 * e.j : 3 * e.j + 3] = 1
    sol = least_squares(residuals, initial.ravel(), jac_sparsity=sparsity, method="trf", x_scale="jac")
    return np.asarray(sol.x).reshape(n, 3)
