"""Dense deformation: graph-node motion carried onto the full-resolution
leaf points. World frame W, metres.

Choice: embedded-deformation blending with Gaussian RBF weights, as in
DynamicFusion (Newcombe 2015; the paper cites it) with linear instead of
dual-quaternion blending. A point x follows its k nearest graph nodes
p_k (within ``radius``):

    x' = sum_k w_k (R_k (x - p_k) + p'_k),  w_k ~ exp(-|x - p_k|^2 / (2 sigma^2)),

normalised to sum 1, where R_k is the node's ARAP rotation. Using R_k
keeps a bent leaf's points on the bent surface between nodes (a plain mean
of node displacements, as in the authors' code with 10 nodes within 5 cm,
smears the motion over ~1 cm and flattens bends). Neighbouring nodes are
5 mm apart, so their rotations differ little and linear blending is safe.
Points whose own voxel node was dropped from the graph (no path to the
handle) do not move.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree


class DenseInterpolator:
    """Weights from dense points ``points_W`` (N, 3) to graph nodes
    ``nodes_W`` (n, 3), built once per grasp graph. ``movable`` (N,) marks
    points that may follow the graph (their voxel node is in it)."""

    def __init__(self, points_W: np.ndarray, nodes_W: np.ndarray, movable: np.ndarray,
                 neighbors: int = 8, radius: float = 0.05, sigma: float = 0.005):
        self.points_W = np.asarray(points_W, dtype=float)
        N, n = len(self.points_W), len(nodes_W)
        k = max(1, min(int(neighbors), n))
        rows = np.flatnonzero(movable)
        d, idx = cKDTree(nodes_W).query(self.points_W[rows], k=k, distance_upper_bound=radius)
        d, idx = d.reshape(len(rows), k), idx.reshape(len(rows), k)
        ok = np.isfinite(d)
        # Gaussian weights relative to the nearest node (avoids underflow far away).
        w = np.where(ok, np.exp(-(d ** 2 - d[:, :1] ** 2) / (2.0 * sigma ** 2)), 0.0)
        tot = w.sum(axis=1)
        has = tot > 0
        w = w[has] / tot[has, None]
        r = np.repeat(rows[has], k)
        self.moved = np.zeros(N, dtype=bool)
        self.moved[rows[has]] = True
        sel = w.ravel() > 0
        self.W = sp.csr_matrix((w.ravel()[sel], (r[sel], np.where(ok[has], idx[has], 0).ravel()[sel])),
                               shape=(N, n))

    def Apply(self, rest_nodes_W: np.ndarray, deformed_nodes_W: np.ndarray,
              rotations: np.ndarray) -> np.ndarray:
        """Deformed dense points (A, N, 3) for node positions
        ``deformed_nodes_W`` (A, n, 3) and rotations (A, n, 3, 3)."""
        A, n = deformed_nodes_W.shape[:2]
        R = np.ascontiguousarray(rotations.transpose(1, 0, 2, 3)).reshape(n, A * 9)
        t = deformed_nodes_W - np.einsum("anij,nj->ani", rotations, rest_nodes_W)
        t = np.ascontiguousarray(t.transpose(1, 0, 2)).reshape(n, A * 3)
        Rbar = (self.W @ R).reshape(-1, A, 3, 3)
        tbar = (self.W @ t).reshape(-1, A, 3)
        out = np.einsum("naij,nj->ani", Rbar, self.points_W) + tbar.transpose(1, 0, 2)
        out[:, ~self.moved] = self.points_W[~self.moved]
        return out
