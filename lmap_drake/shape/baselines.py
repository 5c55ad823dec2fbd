"""Baselines of paper Table I (world frame W, metres).

* SupEps (Marangoz et al. 2022 style): a superellipsoid fitted to the
  observed fruit points by bounded least squares on the Solina radial
  residual sqrt(abc) (F^e1 - 1); semi-axes a, b, c in [2, 15] cm,
  exponents e1, e2 in [0.3, 0.9], centre (within 10 cm of the
  initialisation) and rotation vector. Initialised like SSC (centroid pushed
  1 cm away from the camera, R = I). The peduncle axis is the
  superellipsoid axis closest to world +z (peppers hang; the fit itself has
  no notion of a peduncle).
* HoMa (Pan et al. 2023 style): the same DeepSDF template and optimiser
  as SSC with the surface loss and latent regularisation only (no negative
  points, no peduncle loss).
* TCoRe is not reproduced: its trained weights are not available.
"""
from __future__ import annotations

import dataclasses as dc

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from lmap_drake.shape.marching import ExtractIsoSurface
from lmap_drake.shape.metrics import MeshCentroid
from lmap_drake.shape.config import SscConfig
from lmap_drake.shape.ssc import OptimizeShape, Sim3Matrix
from lmap_drake.types import FruitEstimate


def _supeps_F(x, a, b, c, e1, e2):
    ax, ay, az = (np.abs(x[:, i]) + 1e-12 for i in range(3))
    return ((ax / a) ** (2 / e2) + (ay / b) ** (2 / e2)) ** (e2 / e1) + (az / c) ** (2 / e1)


def FitSuperellipsoid(fruit_points_W: np.ndarray, camera_W: np.ndarray,
                      max_points: int = 600, seed: int = 0,
                      push_from_camera: float = 0.01) -> FruitEstimate:
    """SupEps baseline; returns a FruitEstimate (mesh at 3 mm, X_WO with
    unit scale, latent = [a, b, c, e1, e2])."""
    rng = np.random.default_rng(seed)
    pts = np.asarray(fruit_points_W, float)
    if len(pts) > max_points:
        pts = pts[rng.choice(len(pts), max_points, replace=False)]
    c0 = pts.mean(0)
    away = (c0 - camera_W) / np.linalg.norm(c0 - camera_W)
    t0 = c0 + push_from_camera * away

    def residual(q):
        a, b, c, e1, e2 = q[:5]
        R = Rotation.from_rotvec(q[5:8]).as_matrix()
        x = (pts - q[8:11]) @ R
        F = _supeps_F(x, a, b, c, e1, e2)
        return np.sqrt(a * b * c) * (F ** e1 - 1.0)

    q0 = np.r_[0.04, 0.04, 0.045, 0.6, 0.6, 0, 0, 0, t0]
    lo = np.r_[0.02, 0.02, 0.02, 0.3, 0.3, -np.pi, -np.pi, -np.pi, t0 - 0.1]
    hi = np.r_[0.15, 0.15, 0.15, 0.9, 0.9, np.pi, np.pi, np.pi, t0 + 0.1]
    sol = least_squares(residual, q0, bounds=(lo, hi), method="trf", max_nfev=300,
                        x_scale=np.r_[0.01, 0.01, 0.01, 0.1, 0.1, 0.3, 0.3, 0.3, 0.01, 0.01, 0.01])
    a, b, c, e1, e2 = sol.x[:5]
    R = Rotation.from_rotvec(sol.x[5:8]).as_matrix()
    t = sol.x[8:11]

    def f_local(x):
        return _supeps_F(x, a, b, c, e1, e2) ** (e1 / 2) - 1.0

    ext = np.array([a, b, c])
    vO, faces = ExtractIsoSurface(f_local, -ext, ext, 0.003)
    vW = vO @ R.T + t
    k = int(np.argmax(np.abs(R[2, :])))
    axis = R[:, k] * np.sign(R[2, k] if R[2, k] != 0 else 1.0)

    def sdf_W(p):
        """Approximate signed distance (m): radial scaling of F."""
        x = (np.asarray(p, float).reshape(-1, 3) - t) @ R
        r = np.linalg.norm(x, axis=1)
        return r * (1.0 - _supeps_F(x, a, b, c, e1, e2) ** (-e1 / 2))

    return FruitEstimate(vertices_W=vW, faces=faces, X_WO=Sim3Matrix(1.0, R, t),
                         latent=np.array([a, b, c, e1, e2]),
                         center_W=MeshCentroid(vW, faces) if len(faces) else t,
                         peduncle_axis_W=axis, sdf_W=sdf_W,
                         loss_trace=[dict(cost=float(sol.cost), nfev=int(sol.nfev))])


def HomaParams(params: SscConfig) -> SscConfig:
    """SSC parameters with the scene-consistency terms switched off, and no
    rotation hold (the hold is for SSC's start inside the leaf and free
    space; without scene terms it cost HoMa-style 0.2-0.6 deg of axis)."""
    return dc.replace(params, w_neg=0.0, w_ped=0.0, rotation_hold_steps=0)


def FitHoma(decoder, mean_latent, fruit_points_W, camera_W,
            params: SscConfig | None = None) -> FruitEstimate:
    """HoMa-style baseline: DeepSDF, surface loss + regularisation only."""
    return OptimizeShape(decoder, mean_latent, fruit_points_W, camera_W, negatives=[],
                         branch_samples_W=None, params=HomaParams(params or SscConfig()))
