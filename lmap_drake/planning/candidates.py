"""LMAP action candidates (paper Sec. III-C-1): grasp points on the convex
hull of the PCA-projected leaf, moved inward; gripper orientation from the
leaf normal; the 14 pull directions filtered by the branch-angle rule.
World frame W, metres."""
from __future__ import annotations

import dataclasses as dc

import numpy as np
from scipy.spatial import ConvexHull, cKDTree

from lmap_drake.deformation.action import PullDirections


class PlanningError(ValueError):
    """The planner cannot work on this input (e.g. too few leaf points)."""


@dc.dataclass
class LeafFrame:
    """PCA frame of the leaf points: ``center`` (3), ``axes`` (3x3, columns:
    major, minor, normal), the normal pointing toward the camera."""
    center: np.ndarray
    axes: np.ndarray

    def To2d(self, p_W: np.ndarray) -> np.ndarray:
        return (p_W - self.center) @ self.axes[:, :2]


def LeafPca(leaf_points_W: np.ndarray, p_WC: np.ndarray) -> LeafFrame:
    if len(leaf_points_W) < 10:
        raise PlanningError(f"need at least 10 leaf points, got {len(leaf_points_W)}")
    c = leaf_points_W.mean(axis=0)
    _, _, Vt = np.linalg.svd(leaf_points_W - c, full_matrices=False)
    axes = Vt.T.copy()
    if axes[:, 2] @ (p_WC - c) < 0:
        axes[:, 2] *= -1
    axes[:, 1] = np.cross(axes[:, 2], axes[:, 0])
    return LeafFrame(c, axes)


@dc.dataclass
class Grasp:
    """A grasp pose: TCP at ``p_WG`` with orientation ``R_WG`` (columns x, y,
    z: pads' width direction, closing direction = leaf normal, approach =
    inward along the leaf)."""
    p_WG: np.ndarray
    R_WG: np.ndarray
    grasp_id: int


def GraspCandidates(leaf_points_W: np.ndarray, branch_points_W: np.ndarray,
                    p_WC: np.ndarray, num_grasps: int = 15, inset: float = 0.01,
                    min_branch_distance: float = 0.06) -> tuple[list[Grasp], list[dict]]:
    """``num_grasps`` points evenly spaced along the perimeter of the convex
    hull of the PCA-projected leaf, moved ``inset`` inward. Grasps within
    ``min_branch_distance`` of a branch point are dropped (recorded)."""
    frame = LeafPca(leaf_points_W, p_WC)
    uv = frame.To2d(leaf_points_W)
    hull = ConvexHull(uv)
    poly = uv[hull.vertices]
    seg = np.roll(poly, -1, axis=0) - poly
    seg_len = np.linalg.norm(seg, axis=1)
    cum = np.r_[0, np.cumsum(seg_len)]
    targets = (np.arange(num_grasps) + 0.5) / num_grasps * cum[-1]
    tree = cKDTree(uv)
    branch_tree = cKDTree(branch_points_W) if len(branch_points_W) else None
    grasps, dropped = [], []
    center2 = poly.mean(axis=0)
    for k, s in enumerate(targets):
        i = int(np.searchsorted(cum, s, side="right") - 1)
        i = min(i, len(poly) - 1)
        p2 = poly[i] + seg[i] * (s - cum[i]) / max(seg_len[i], 1e-12)
        n_out = np.array([seg[i, 1], -seg[i, 0]]) / max(seg_len[i], 1e-12)
        if n_out @ (p2 - center2) < 0:
            n_out = -n_out
        q2 = p2 - inset * n_out
        # lift to 3D: mean of the nearest leaf points around the inset point
        _, idx = tree.query(q2, k=min(8, len(uv)))
        p_W = leaf_points_W[np.atleast_1d(idx)].mean(axis=0)
        if branch_tree is not None and branch_tree.query(p_W)[0] < min_branch_distance:
            dropped.append({"grasp_id": k, "reason": "within "
                            f"{min_branch_distance * 100:.0f} cm of the branch"})
            continue
        # Pads close across the leaf where it is grasped: the local normal
        # (PCA of the leaf points within 2 cm), approach inward in that plane.
        y = _LocalNormal(leaf_points_W, p_W, frame.axes[:, 2])
        z = -(frame.axes[:, :2] @ n_out)
        z = z - (z @ y) * y
        z /= np.linalg.norm(z)
        x = np.cross(y, z)
        grasps.append(Grasp(p_W, np.c_[x, y, z], k))
    return grasps, dropped


def _LocalNormal(points: np.ndarray, p: np.ndarray, toward: np.ndarray,
                 radius: float = 0.02) -> np.ndarray:
    """Unit normal of the points within ``radius`` of ``p`` (least-variance
    direction), oriented like ``toward``; ``toward`` if too few points."""
    near = points[np.linalg.norm(points - p, axis=1) < radius]
    if len(near) < 8:
        return toward
    _, _, Vt = np.linalg.svd(near - near.mean(axis=0), full_matrices=False)
    n = Vt[2]
    return n if n @ toward >= 0 else -n


def DirectionsForGrasp(p_WG: np.ndarray, branch_points_W: np.ndarray,
                       max_angle_deg: float = 120.0,
                       directions: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The pull directions (and their indices into ``PullDirections()``) whose
    angle to the line from the grasp point to the nearest branch point is
    below ``max_angle_deg``: the leaf is not pulled away from its branch."""
    D = PullDirections() if directions is None else np.asarray(directions, float)
    if len(branch_points_W) == 0:
        return D, np.arange(len(D))
    nearest = branch_points_W[cKDTree(branch_points_W).query(p_WG)[1]]
    to_branch = nearest - p_WG
    to_branch /= max(np.linalg.norm(to_branch), 1e-12)
    keep = np.flatnonzero(D @ to_branch > np.cos(np.deg2rad(max_angle_deg)))
    return D[keep], keep
