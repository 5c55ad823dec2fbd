"""View fusion (paper Sec. III-E): after the leaf has been moved, the new
view is fused with the earlier ones before shape re-estimation.

Leaf points come from the newest view only (the leaf moved, so its old
points are stale); fruit and branch points (rigid, not touched) accumulate
and are re-voxelised. New instances take the id of the earlier instance
they overlap (nearest-neighbour distance within ``match_distance``), else a
fresh id. All points are in the world frame W, metres.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from lmap_drake.perception.points import VoxelDownsample
from lmap_drake.types import SemanticScene

_NAMES = ("branch", "leaf", "fruit")


def _match_instances(old_pts, old_inst, new_pts, new_inst, match_distance):
    """New instance ids rewritten onto the old ids they overlap."""
    out = new_inst.copy()
    if len(old_pts) == 0 or len(new_pts) == 0:
        return out
    next_id = int(max(old_inst.max(initial=-1), -1)) + 1
    tree = cKDTree(old_pts)
    for i in np.unique(new_inst):
        m = new_inst == i
        dist, j = tree.query(new_pts[m], k=1)
        close = dist <= match_distance
        if i < 0:  # unassigned points take the instance of a close old point
            out[np.nonzero(m)[0][close]] = old_inst[j[close]]
            continue
        if close.mean() >= 0.2:
            ids, counts = np.unique(old_inst[j[close]], return_counts=True)
            best = ids[np.argmax(counts)]
            if best >= 0:
                out[m] = best
                continue
        out[m] = next_id
        next_id += 1
    return out


def _FusedConfidence(old: dict, new: dict, new_inst: np.ndarray, new_ids: np.ndarray) -> dict:
    """The fused fruit instances' confidences: an instance seen in both
    views keeps the higher one (a fruit segmented confidently in one view
    is a fruit; a phantom is unsure in each). ``new_inst``: the new view's
    instance per point, ``new_ids``: the fused id it was given."""
    out = dict(old)
    for i, c in new.items():
        m = new_inst == i
        if not m.any():
            continue
        j = int(new_ids[np.flatnonzero(m)[0]])
        out[j] = max(c, out.get(j, c))
    return out


def _SameCameraPose(X_a, X_b, tol_m: float = 1e-3, tol_rad: float = 1e-3) -> bool:
    A, B = np.asarray(X_a, float), np.asarray(X_b, float)
    cos = np.clip((np.trace(A[:3, :3].T @ B[:3, :3]) - 1) / 2, -1.0, 1.0)
    return bool(np.linalg.norm(A[:3, 3] - B[:3, 3]) <= tol_m and np.arccos(cos) <= tol_rad)


def FuseViews(previous: SemanticScene | None, new: SemanticScene, voxel_size: float = 0.003,
              match_distance: float = 0.008) -> SemanticScene:
    """Fuses ``new`` into ``previous`` (either may be empty; ``previous`` may
    be None). Returns a new SemanticScene with ``X_WC`` of the newest view,
    ``num_views`` summed and flags recomputed (plus ``fused_views``). The
    leaf comes from ``new`` only (it moved); background rays are united
    when the camera pose is unchanged, else ``new``'s."""
    if previous is None:
        return new
    fused = SemanticScene(X_WC=np.asarray(new.X_WC, float).copy())
    fused.leaf_points_W = np.asarray(new.leaf_points_W, float).copy()
    fused.leaf_instance = np.asarray(new.leaf_instance, np.int64).copy()
    for name in ("branch", "fruit"):
        old_p = np.asarray(getattr(previous, f"{name}_points_W"), float).reshape(-1, 3)
        old_i = np.asarray(getattr(previous, f"{name}_instance"), np.int64)
        new_p = np.asarray(getattr(new, f"{name}_points_W"), float).reshape(-1, 3)
        new_i = _match_instances(old_p, old_i, new_p,
                                 np.asarray(getattr(new, f"{name}_instance"), np.int64),
                                 match_distance)
        pts, inst = VoxelDownsample(np.concatenate([old_p, new_p]),
                                    voxel_size, np.concatenate([old_i, new_i]))
        setattr(fused, f"{name}_points_W", pts)
        setattr(fused, f"{name}_instance", inst)
        if name == "fruit":
            fused.fruit_confidence = _FusedConfidence(
                getattr(previous, "fruit_confidence", {}), getattr(new, "fruit_confidence", {}),
                np.asarray(new.fruit_instance, np.int64), new_i)
    # Background rays are carved from the newest camera centre: an earlier
    # view's rays only join when the camera has not moved (eye-to-hand).
    fused.background_points_W = np.asarray(new.background_points_W, float).reshape(-1, 3)
    if _SameCameraPose(previous.X_WC, new.X_WC):
        fused.background_points_W = np.unique(np.concatenate(
            [np.asarray(previous.background_points_W, float).reshape(-1, 3),
             fused.background_points_W]), axis=0)
    fused.num_views = int(getattr(previous, "num_views", 1)) + int(getattr(new, "num_views", 1))
    flags = ["fused_views"]
    for name in _NAMES:
        if len(getattr(fused, f"{name}_points_W")) == 0:
            flags.append(f"no_{name}_in_view")
    if fused.is_empty():
        flags.append("empty_scene")
    # keep the newest view's other conditions (e.g. green_fruit_detected)
    flags += [f for f in new.flags if f not in flags and not f.startswith("no_")
              and f != "empty_scene"]
    fused.flags = flags
    return fused
