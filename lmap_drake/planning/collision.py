"""Collision checks of the LMAP planner (paper Sec. III-C-1): robot vs fruit
and deformed leaf vs fruit through the completed fruit's SDF, robot vs branch
through the distance to the completed branch mesh (Open3D ray-casting scene,
batched). Margin in metres; world frame W."""
from __future__ import annotations

import numpy as np


class BranchDistance:
    """Unsigned distance (m) to a triangle mesh (the completed branch),
    batched with Open3D's RaycastingScene."""

    def __init__(self, vertices_W: np.ndarray, faces: np.ndarray):
        import open3d as o3d
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(o3d.core.Tensor(np.asarray(vertices_W, np.float32)),
                                  o3d.core.Tensor(np.asarray(faces, np.uint32)))

    def __call__(self, points_W: np.ndarray) -> np.ndarray:
        import open3d as o3d
        if len(points_W) == 0:
            return np.zeros(0)
        q = o3d.core.Tensor(np.asarray(points_W, np.float32))
        return self._scene.compute_distance(q).numpy().astype(float)


def NearBox(points_W: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Points inside the axis-aligned box [lo, hi] (a cheap pre-filter)."""
    return points_W[np.all((points_W >= lo) & (points_W <= hi), axis=1)]


def RobotCollisionReason(robot_points_W: np.ndarray, fruit_sdf, branch_distance,
                         margin: float, fruit_box=None, branch_box=None) -> str:
    """'' if the robot samples keep ``margin`` from the fruit (SDF) and the
    branch mesh, else the reason. ``*_box`` = (lo, hi) bounds of each
    object; only samples within ``margin`` of those bounds are queried."""
    for name, distance, box in (("fruit", fruit_sdf, fruit_box),
                                ("branch", branch_distance, branch_box)):
        if distance is None:
            continue
        pts = robot_points_W if box is None else NearBox(
            robot_points_W, box[0] - margin, box[1] + margin)
        if len(pts):
            d = np.asarray(distance(pts), float)
            if np.isfinite(margin) and not np.all(np.isfinite(d)):
                # NaN passes every comparison: a non-finite distance rejects.
                return f"robot-{name} (non-finite {name} distance)"
            if d.min() < margin:
                return f"robot-{name} ({d.min() * 1000:.1f} mm)"
    return ""


def LeafFruitCollisionReason(rest_W: np.ndarray, deformed_W: np.ndarray, fruit_sdf,
                             margin: float, fruit_box=None, rest_sdf=None) -> str:
    """'' unless a leaf point ends within ``margin`` of the fruit surface (or
    inside it) after moving toward the fruit. Leaf points that already rest
    that close and do not approach are not counted (a leaf lying on its
    fruit is not a collision caused by the action). ``fruit_box`` (lo, hi):
    only deformed points within ``margin`` of it are evaluated (the others
    are farther than ``margin`` from the fruit); ``rest_sdf``: the SDF at
    ``rest_W``, when already known (one evaluation for many actions)."""
    if fruit_sdf is None or deformed_W is None or len(deformed_W) == 0:
        return ""
    deformed_W = np.asarray(deformed_W, float)
    sel = np.ones(len(deformed_W), bool)
    if fruit_box is not None:
        lo, hi = np.asarray(fruit_box[0]) - margin, np.asarray(fruit_box[1]) + margin
        sel = np.all((deformed_W >= lo) & (deformed_W <= hi), axis=1)
        if not sel.any():
            return ""
    d1 = np.asarray(fruit_sdf(deformed_W[sel]), float)
    d0 = (np.asarray(rest_sdf, float)[sel] if rest_sdf is not None
          else np.asarray(fruit_sdf(np.asarray(rest_W)[sel]), float))
    if not (np.all(np.isfinite(d1)) and np.all(np.isfinite(d0))):
        return "leaf-fruit (non-finite fruit SDF)"
    bad = (d1 < margin) & (d1 < d0 - 1e-3)
    if bad.any():
        return f"leaf-fruit ({d1[bad].min() * 1000:.1f} mm)"
    return ""
