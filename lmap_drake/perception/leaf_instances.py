"""Leaf instances against the true leaves, and the planner's leaf instances
painted back on the pixels they came from.

``LeafInstanceScores`` compares an HxW instance map (-1 = none) with the
render labels' true leaf ids; ``PointLeafInstances`` runs the point
pipeline's leaf step (``points.ClassPoints``: outlier removal, DBSCAN,
voxels; then ``SplitTouchingLeaves`` and ``SplitOversizedLeaves`` as
``shape.completion.CompletePlant`` does) and gives each leaf pixel the
instance of its voxel (-1: dropped as an outlier, flying pixel or DBSCAN
noise).
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from lmap_drake.labels import LEAF
from lmap_drake.perception.leaf_boundaries import ImagePatches, SplitAtNecks, SplitClustersByPatches
from lmap_drake.perception.points import (AssignToParts, DbscanLabels, DeprojectPixels,
                                          FlyingPixelMask, Intrinsics, SplitOversizedLeaves, SplitTouchingLeaves,
                                          StatisticalOutlierMask, ValidDepthMask)

MATCH_IOU = 0.5        # a true leaf is matched when an instance reaches this IoU with it
MERGE_SHARE = 0.5      # an instance holding this share of two true leaves merges them
SPLIT_SHARE = 0.2      # two instances each holding this share of a true leaf split it


def LeafInstanceScores(pred: np.ndarray, truth: np.ndarray, min_pixels: int = 200,
                       ignore: np.ndarray | None = None) -> dict:
    """Scores of the leaf instance map ``pred`` (HxW int, -1 = not a leaf
    instance) against the true leaf ids ``truth`` (HxW int, -1 = not a
    leaf). Pixels where ``ignore`` is true (a neighbouring plant) are left
    out. Only true leaves with at least ``min_pixels`` visible pixels count:

    - ``best_iou``: per true leaf, the largest IoU of any instance with it;
    - ``matched``: true leaves whose best IoU is at least ``MATCH_IOU``;
    - ``merges``: instances holding ``MERGE_SHARE`` or more of the pixels of
      each of two or more counted true leaves (one instance, several leaves);
    - ``splits``: counted true leaves of which two or more instances each
      hold ``SPLIT_SHARE`` or more (one leaf, several instances);
      ``splits_visible_apart`` of them are seen in two or more pieces of
      that share (a stem or leaf in front cuts them: no grouping by
      connectivity can join them);
    - ``instances``: instances of at least ``min_pixels`` pixels."""
    pred = np.asarray(pred, np.int64)
    truth = np.asarray(truth, np.int64)
    if ignore is not None:
        keep = ~np.asarray(ignore, bool)
        pred = np.where(keep, pred, -1)
        truth = np.where(keep, truth, -1)
    t_ids, t_n = np.unique(truth[truth >= 0], return_counts=True)
    p_ids, p_n = np.unique(pred[pred >= 0], return_counts=True)
    leaves = t_ids[t_n >= min_pixels]
    out = {"leaves": int(len(leaves)), "instances": int(np.sum(p_n >= min_pixels)),
           "matched": 0, "merges": 0, "splits": 0, "splits_visible_apart": 0, "best_iou": []}
    if len(leaves) == 0:
        return out
    both = (truth >= 0) & (pred >= 0)
    ti = np.searchsorted(t_ids, truth[both])
    pi = np.searchsorted(p_ids, pred[both])
    inter = np.zeros((len(t_ids), len(p_ids)), np.int64)
    np.add.at(inter, (ti, pi), 1)
    union = t_n[:, None] + p_n[None, :] - inter
    iou = inter / np.maximum(union, 1)
    share = inter / t_n[:, None]                       # of each true leaf, per instance
    counted = np.isin(t_ids, leaves)
    best = iou[counted].max(axis=1) if len(p_ids) else np.zeros(int(counted.sum()))
    out["best_iou"] = [round(float(b), 3) for b in best]
    out["matched"] = int(np.sum(best >= MATCH_IOU))
    out["merges"] = int(np.sum((share[counted] >= MERGE_SHARE).sum(axis=0) >= 2))
    split = np.flatnonzero(counted & ((share >= SPLIT_SHARE).sum(axis=1) >= 2))
    out["splits"] = int(len(split))
    apart = 0
    for k in split:                    # the leaf's visible pixels in pieces: no grouping joins them
        lab, n = ndimage.label(truth == t_ids[k], structure=np.ones((3, 3)))
        if n > 1 and np.sum(np.bincount(lab.ravel())[1:] >= SPLIT_SHARE * t_n[k]) >= 2:
            apart += 1
    out["splits_visible_apart"] = apart
    return out


def SummariseLeafInstances(rows: list[dict]) -> dict:
    """Over the views' ``LeafInstanceScores``: ``matched_fraction`` (of all
    counted true leaves), ``mean_best_iou``, ``merges_per_view``,
    ``splits_per_view`` (``splits_visible_apart_per_view`` of them seen in
    pieces), ``leaves``, ``views``."""
    best = [b for r in rows for b in r["best_iou"]]
    n = max(len(rows), 1)
    leaves = sum(r["leaves"] for r in rows)
    return {"matched_fraction": round(sum(r["matched"] for r in rows) / max(leaves, 1), 3),
            "mean_best_iou": round(float(np.mean(best)), 3) if best else None,
            "merges_per_view": round(sum(r["merges"] for r in rows) / n, 3),
            "splits_per_view": round(sum(r["splits"] for r in rows) / n, 3),
            "splits_visible_apart_per_view": round(
                sum(r.get("splits_visible_apart", 0) for r in rows) / n, 3),
            "leaves": leaves, "views": len(rows)}


def PointLeafInstances(class_map: np.ndarray, depth: np.ndarray, K: Intrinsics, params,
                       split_angle_deg: float = 15.0, check_spread: bool = True,
                       neck_ratio: float = 0.5, boundary: np.ndarray | None = None
                       ) -> np.ndarray:
    """HxW leaf instance ids (-1 = none) the planner would get from
    ``class_map``'s leaf pixels: the leaf step of ``points.BuildSemanticScene``
    (depth cut, flying pixels, outlier removal, DBSCAN, voxels of
    ``params.voxel_size``; ``params`` a ``PerceptionConfig``) and the splits
    of ``shape.completion.CompletePlant`` (``split_angle_deg``; 0 = none;
    ``neck_ratio`` as ``SplitLeafNecks``, 0 = not; ``check_spread`` as
    ``SplitOversizedLeaves``), in the camera frame; each pixel takes its voxel's instance.
    ``boundary`` (HxW bool, ``Segmentation.leaf_boundary``): clusters cut
    along it as ``points.BuildSemanticScene`` does."""
    d = np.asarray(depth, np.float64)
    out = np.full(d.shape, -1, np.int64)
    valid = ValidDepthMask(d, params.depth_cut) & ~FlyingPixelMask(d, params.flying_pixel_jump)
    m = (np.asarray(class_map) == LEAF) & valid
    pts = DeprojectPixels(d, m, K)
    if len(pts) == 0:
        return out
    v, u = np.nonzero(m)                        # DeprojectPixels' order
    keep = StatisticalOutlierMask(pts, params.outlier_neighbors, params.outlier_std_ratio)
    pts, v, u = pts[keep], v[keep], u[keep]
    inst = DbscanLabels(pts, params.dbscan_eps, params.dbscan_min_points)
    if boundary is not None:
        patch, cannot = ImagePatches(m, boundary)
        inst = SplitClustersByPatches(pts, inst, patch[v, u], cannot)
    if params.voxel_size > 0:                   # as points.VoxelDownsample
        keys = np.concatenate([np.floor(pts / params.voxel_size).astype(np.int64),
                               inst[:, None]], axis=1)
        _, cell, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
        cell = cell.ravel()
        sums = np.zeros((len(counts), 3))
        np.add.at(sums, cell, pts)
        vox = sums / counts[:, None]
        vox_inst = np.full(len(counts), -1, np.int64)
        vox_inst[cell] = inst
    else:
        cell, vox, vox_inst = np.arange(len(pts)), pts, inst
    if split_angle_deg > 0:
        vox_inst = SplitTouchingLeaves(vox, vox_inst, np.zeros(3), split_angle_deg)
        if neck_ratio > 0:
            vox_inst = SplitLeafNecks(vox, vox_inst, params.voxel_size, neck_ratio)
        vox_inst = SplitOversizedLeaves(vox, vox_inst, check_spread=check_spread)
    out[v, u] = vox_inst[cell]
    return out


def SplitLeafNecks(leaf_W: np.ndarray, leaf_instance: np.ndarray, voxel: float = 0.003,
                   neck_ratio: float = 0.5, min_points: int = 30) -> np.ndarray:
    """Leaf instance ids (N,) with blades that touch at one depth and one
    angle told apart by their outline (``SplitAtNecks``): each instance's
    points, laid in their best-fit plane (PCA) on a grid of ``voxel`` m
    cells (closed by one cell: voxel centroids leave gaps), are cut where
    the outline narrows to a neck. Parts of fewer than ``min_points`` go
    back to the nearest part; the largest part keeps the id, new ids are
    appended; noise (-1) stays noise."""
    leaf_W = np.asarray(leaf_W, float).reshape(-1, 3)
    ids = np.asarray(leaf_instance, np.int64).copy()
    if voxel <= 0 or neck_ratio <= 0 or len(ids) == 0:
        return ids
    next_id = int(ids.max()) + 1
    for j in np.unique(ids[ids >= 0]):
        mine = np.flatnonzero(ids == j)
        if len(mine) < 2 * min_points:
            continue
        p = leaf_W[mine] - leaf_W[mine].mean(axis=0)
        _, _, vt = np.linalg.svd(p, full_matrices=False)
        ab = p @ vt[:2].T
        cell = np.floor((ab - ab.min(axis=0)) / voxel).astype(np.int64) + 2
        grid = np.zeros(tuple(cell.max(axis=0) + 3), bool)
        grid[cell[:, 0], cell[:, 1]] = True
        grid = ndimage.binary_closing(grid, structure=np.ones((3, 3)))
        parts, k = SplitAtNecks(grid, neck_ratio)
        if k < 2:
            continue
        part = parts[cell[:, 0], cell[:, 1]]
        sizes = np.bincount(part[part >= 0], minlength=k)
        big = np.flatnonzero(sizes >= min_points)
        if len(big) < 2:
            continue
        next_id = AssignToParts(ids, mine, ab, part, big, sizes, j, next_id)
    return ids
