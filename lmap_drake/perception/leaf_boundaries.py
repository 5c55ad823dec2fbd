"""Leaf instances cut along the segmenter's leaf boundaries.

Two blades that lie flush (a few millimetres apart, at one angle) are one
DBSCAN cluster in 3D: no distance or normal test tells them apart, yet the
image does, along the line where one blade's edge crosses the other. A
segmenter that marks that line (``Segmentation.leaf_boundary``: the label
oracle from the render's leaf ids, segnet from its boundary head) lets the
point pipeline cut the cluster there:

1. ``ImagePatches``: the leaf pixels minus the boundary band fall into
   connected patches; two patches that face each other across the band
   along at least ``min_contact`` pixel pairs may not be one leaf (a
   cannot-link pair). Boundary pixels join their nearest patch.
2. ``SplitClustersByPatches``: each DBSCAN cluster's patches, largest
   first, join the nearest (3D) group they have no cannot-link pair with,
   or start a group. Patches that do not face each other (a leaf seen in
   two pieces either side of a stem) are free to join: only a marked
   boundary cuts. Groups of fewer than ``min_points`` points join their
   nearest group whatever the links.

A boundary that leaks (a gap in the band) leaves the two patches one: the
cut is never worse than no cut.
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

# (row, column) steps across the band: four directions (the other four are
# the same pairs reversed), 1 .. _REACH pixels
_DIRECTIONS = ((0, 1), (1, 0), (1, 1), (1, -1))


def BandCounts(predicted: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(hit, predicted, true) pixel counts of a predicted boundary band
    against the true band (bool arrays of the pixels scored, e.g. the true
    leaf pixels)."""
    predicted, truth = np.asarray(predicted, bool), np.asarray(truth, bool)
    return np.array([(predicted & truth).sum(), predicted.sum(), truth.sum()], np.int64)


def BandPrecisionRecall(counts) -> tuple[float | None, float | None]:
    """(precision, recall) from summed ``BandCounts``, rounded to 4 digits;
    None where nothing was predicted / nothing is true."""
    hit, said, true = (int(c) for c in counts)
    return (round(hit / said, 4) if said else None, round(hit / true, 4) if true else None)


def _Shift(x: np.ndarray, dr: int, dc: int) -> np.ndarray:
    """y[r, c] = x[r + dr, c + dc], zero (False) outside."""
    y = np.zeros_like(x)
    H, W = x.shape
    y[max(0, -dr):H - max(0, dr), max(0, -dc):W - max(0, dc)] = \
        x[max(0, dr):H - max(0, -dr), max(0, dc):W - max(0, -dc)]
    return y


def ImagePatches(leaf: np.ndarray, boundary: np.ndarray, reach: int = 8,
                 min_contact: int = 8, neck_ratio: float = 0.35) -> tuple[np.ndarray, set]:
    """(HxW patch ids, 0 = not a leaf pixel; cannot-link pairs {(a, b), a < b})
    of the ``leaf`` pixels (HxW bool) cut by the ``boundary`` pixels (HxW
    bool): 8-connected patches of leaf and not boundary, the boundary pixels
    then given to their nearest patch. A pair of patches cannot link when at
    least ``min_contact`` pixel pairs, one in each patch and at most
    ``reach`` pixels apart along a row, column or diagonal, have only
    boundary pixels between them. A band with a gap leaves one patch joined
    through a neck: patches that touch the band are first cut at their
    necks (``SplitAtNecks`` at ``neck_ratio``; 0 = not), and the parts
    facing each other across the band then cannot link (parts that only
    meet at a neck stay free to join)."""
    leaf = np.asarray(leaf, bool)
    band = np.asarray(boundary, bool) & leaf
    core = leaf & ~band
    patch, n = ndimage.label(core, structure=np.ones((3, 3)))
    cannot: set = set()
    if n == 0:
        return np.zeros(leaf.shape, np.int64), cannot
    if neck_ratio > 0 and band.any():     # only the patches the band touches
        near = ndimage.binary_dilation(band, structure=np.ones((3, 3)))
        patch, n = SplitRegionsAtNecks(patch, n, neck_ratio,
                                       set(np.unique(patch[near & (patch > 0)]).tolist()))
    if n > 1 and band.any():
        counts: dict = {}
        for dr, dc in _DIRECTIONS:
            between = np.ones(leaf.shape, bool)   # every pixel so far along the step is band
            for k in range(1, reach + 1):
                other = _Shift(patch, k * dr, k * dc)
                hit = between & (patch > 0) & (other > 0) & (other != patch)
                if hit.any():
                    lo = np.minimum(patch[hit], other[hit])
                    hi = np.maximum(patch[hit], other[hit])
                    keys, c = np.unique(lo * (n + 1) + hi, return_counts=True)
                    for key, cnt in zip(keys, c):
                        counts[int(key)] = counts.get(int(key), 0) + int(cnt)
                between &= _Shift(band, k * dr, k * dc)
                if not between.any():
                    break
        cannot = {(int(k // (n + 1)), int(k % (n + 1))) for k, c in counts.items()
                  if c >= min_contact}
    out = patch.astype(np.int64)
    if band.any():
        _, (iy, ix) = ndimage.distance_transform_edt(patch == 0, return_indices=True)
        out[band] = patch[iy[band], ix[band]]
    out[~leaf] = 0
    return out, cannot


def SplitRegionsAtNecks(lab: np.ndarray, n: int, neck_ratio: float, only=None
                        ) -> tuple[np.ndarray, int]:
    """Regions ``lab`` (HxW ids 1..n, 0 = none) with every region of 50
    pixels or more (of ``only``, a set of ids, when given) cut at its necks
    (``SplitAtNecks``); new parts get ids from n + 1 on."""
    lab = lab.copy()
    for i, sl in enumerate(ndimage.find_objects(lab), start=1):
        if sl is None or (only is not None and i not in only):
            continue
        mine = lab[sl] == i
        if mine.sum() < 50:
            continue
        parts, k = SplitAtNecks(mine, neck_ratio)
        view = lab[sl]
        for p in range(1, k):
            n += 1
            view[mine & (parts == p)] = n
    return lab, n


def SplitClustersByPatches(points: np.ndarray, instance: np.ndarray, patch: np.ndarray,
                           cannot: set, min_points: int = 150) -> np.ndarray:
    """Instance ids (N,) of ``points`` (N, 3, m) with every cluster of
    ``instance`` (-1 = noise, kept) cut along cannot-link pairs of the
    points' image patches ``patch`` (N, 0 = none; see the module
    docstring). The largest group keeps the cluster's id; new ids are
    appended."""
    ids = np.asarray(instance, np.int64).copy()
    patch = np.asarray(patch, np.int64)
    if not cannot or len(ids) == 0:
        return ids
    linked = {p for pair in cannot for p in pair}
    next_id = int(ids.max()) + 1
    for j in np.unique(ids[ids >= 0]):
        mine = np.flatnonzero(ids == j)
        ps, sizes = np.unique(patch[mine], return_counts=True)
        if not linked & set(ps.tolist()) or len(ps) < 2:
            continue
        order = np.argsort(-sizes, kind="stable")
        groups: list[list[int]] = []             # patch ids per group
        trees: list[cKDTree] = []
        members: dict[int, np.ndarray] = {int(p): mine[patch[mine] == p] for p in ps}
        for i in order:
            p = int(ps[i])
            if p == 0:
                continue
            ok = [g for g, grp in enumerate(groups)
                  if not any((min(p, q), max(p, q)) in cannot for q in grp)]
            if not ok:
                groups.append([p])
                trees.append(cKDTree(points[members[p]]))
                continue
            pts = points[members[p]]
            best = min(ok, key=lambda g: trees[g].query(pts, k=1)[0].min())
            groups[best].append(p)
            trees[best] = cKDTree(points[np.concatenate([members[q] for q in groups[best]])])
        if len(groups) < 2:
            continue
        size = [sum(len(members[q]) for q in grp) for grp in groups]
        big = [g for g in range(len(groups)) if size[g] >= min_points]
        if len(big) < 2:
            continue
        label = np.full(len(mine), -1, np.int64)
        for g in big:
            for q in groups[g]:
                label[np.searchsorted(mine, members[q])] = g   # ``mine`` is sorted
        rest = label < 0                         # small groups and patch-0 points: nearest big group
        if rest.any():
            tree = cKDTree(points[mine[~rest]])
            _, nn = tree.query(points[mine[rest]], k=1)
            label[rest] = label[~rest][nn]
        first = max(big, key=lambda g: size[g])
        for g in big:
            if g != first:
                ids[mine[label == g]] = next_id
                next_id += 1
    return ids


def SplitAtNecks(mask: np.ndarray, neck_ratio: float = 0.5, min_radius: float = 3.0
                 ) -> tuple[np.ndarray, int]:
    """(HxW part ids, -1 outside ``mask``; number of parts) of one region
    cut where its outline narrows to a neck: a leaf blade is convex in
    outline, so the distance to the outline rises to one ridge; two blades
    touching side by side or tip to edge at one depth join through a neck.
    Every peak of that distance (a local maximum of at least ``min_radius``
    pixels) whose pixels at or above ``neck_ratio`` times its height do not
    reach a higher peak is a blade (the way to any higher peak passes a
    neck narrower than ``neck_ratio`` of it); the blades' peaks seed a
    watershed of the distance (``_GrowDownDistance``) that gives every
    pixel of ``mask`` to one part. A region with one blade is one part
    (ids 0). Scale-free: the same for a leaf near or far."""
    mask = np.asarray(mask, bool)
    out = np.full(mask.shape, -1, np.int64)
    if not mask.any():
        return out, 0
    dist = ndimage.distance_transform_edt(np.pad(mask, 1))[1:-1, 1:-1]
    out[mask] = 0
    if dist.max() < 2 * min_radius:
        return out, 1
    peaks = mask & (dist >= min_radius) & (dist >= ndimage.maximum_filter(dist, size=5))
    lab, n = ndimage.label(peaks, structure=np.ones((3, 3)))
    if n <= 1:
        return out, 1
    height = np.asarray(ndimage.maximum(dist, lab, index=np.arange(1, n + 1)))
    seeds = np.full(mask.shape, -1, np.int64)
    kept = 0
    for i in np.argsort(-height, kind="stable"):
        level, _ = ndimage.label(dist >= neck_ratio * height[i], structure=np.ones((3, 3)))
        mine = level[lab == i + 1][0]
        if (dist[level == mine] > height[i]).any() or (seeds[level == mine] >= 0).any():
            continue                   # reaches a higher (or an earlier) peak: no neck
        seeds[lab == i + 1] = kept
        kept += 1
    if kept <= 1:
        return out, 1
    parts = _GrowDownDistance(seeds, dist, mask)
    out[mask] = parts[mask]
    return out, kept


def _GrowDownDistance(seeds: np.ndarray, dist: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Watershed by flooding: ``seeds`` (HxW, -1 = none) grow, one pixel
    step at a time, into the ``mask`` pixels at or above a level of
    ``dist`` that falls by one pixel per round (the basins meet along the
    necks); pixels still unreached take the nearest part."""
    parts = np.where(mask, seeds, -1)
    for level in np.arange(np.floor(dist.max()), -1.0, -1.0):
        allowed = mask & (dist >= level)
        for _ in range(4 * int(dist.max()) + 4):
            todo = allowed & (parts < 0)
            if not todo.any():
                break
            grown = ndimage.grey_dilation(parts, size=(3, 3))
            take = todo & (grown >= 0)
            if not take.any():
                break
            parts[take] = grown[take]
    lost = mask & (parts < 0)
    if lost.any() and (parts >= 0).any():
        _, (iy, ix) = ndimage.distance_transform_edt(parts < 0, return_indices=True)
        parts[lost] = parts[iy[lost], ix[lost]]
    return parts
