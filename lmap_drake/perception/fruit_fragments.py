"""One fruit seen in pieces, joined back into one instance.

A leaf's rim or a thin stem in front of a fruit, or a few of its pixels
called leaf or branch where they cross it, cut the fruit's pixels into
fragments; per-class connected components (``segmentation.InstancesFromComponents``)
then give each its own instance, and each is taken for a fruit of its own
(two prompts for SAM, two smaller confidences for the planner).
``JoinFruitFragments`` joins two fruit instances when all of these hold:

- **pieces, not specks**: each has at least ``MIN_FRAGMENT_PIXELS``
  pixels (specks called fruit are mostly phantoms: on the greenhouse
  suite's stills 20 of 22 joins of smaller pieces joined specks of no
  fruit, and a phantom grown by its specks passes the size floors that
  keep phantoms out of the planner);
- **a thin strip apart**: they come within ``max_gap`` m of each other in
  the image (converted to pixels at their depth, at least ``MIN_GAP_PX``);
- **the strip is an occluder, not a gap**: at least ``STRIP_PLANT_SHARE``
  of the strip's pixels are plant (leaf or branch) with a return no farther
  than ``BEHIND_TOLERANCE`` m behind the pieces' nearest pixels, so the
  fruit could go on under it (background or a farther surface between
  them is a gap between two fruits);
- **one surface**: the facing borders' median depths differ by at most
  ``depth_jump`` m, the jump at which the components are cut apart;
- **one fruit's size**: the joined points (camera frame) span at most
  ``max_extent`` m along their principal axis.

``DropFruitSpecks`` (``perception.min_fruit_pixels``) calls a speck of
fruit far from any larger fruit instance its pixels' next most probable
class: fewer pixels than ``shape.min_fruit_points`` give fewer points (one
per pixel at most), so no fruit is completed from it, yet its pixels
counted as fruit in the view (a fruitless view of ``gh_random_5353_002``
had 13 such pixels and a fruit IoU of 0).

The largest fruit the project generates is 14.5 cm long (an elongated
greenhouse pepper, 8.5 cm x 1.7); two touching fruits side by side span
more than one. Functional core: numpy on images, no Diagram.
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from lmap_drake.labels import BACKGROUND, FRUIT
from lmap_drake.perception.points import DeprojectPixels, Intrinsics, ValidDepthMask

MAX_GAP = 0.012            # m: a thin stem or a leaf's rim in front of the fruit
MIN_GAP_PX = 2
MIN_FRAGMENT_PIXELS = 30   # as perception.sam_min_prompt_pixels: smaller pieces prompt nothing
STRIP_PLANT_SHARE = 0.8
BEHIND_TOLERANCE = 0.005   # m
MAX_FRUIT_EXTENT = 0.15    # m, along the joined points' principal axis
MAX_POINTS = 3000          # points per extent test (a regular subsample)


def _Extent(points: np.ndarray) -> float:
    """Span (m) of ``points`` along their principal axis."""
    if len(points) < 2:
        return 0.0
    if len(points) > MAX_POINTS:
        points = points[:: int(np.ceil(len(points) / MAX_POINTS))]
    c = points - points.mean(axis=0)
    _, _, Vt = np.linalg.svd(c, full_matrices=False)
    s = c @ Vt[0]
    return float(s.max() - s.min())


def _Median(depth: np.ndarray, mask: np.ndarray) -> float:
    v = depth[mask & np.isfinite(depth)]
    return float(np.median(v)) if len(v) else float("nan")


def _OccluderShare(strip: np.ndarray, plant: np.ndarray, d: np.ndarray, a: np.ndarray,
                   b: np.ndarray) -> float:
    """Share of the ``strip`` pixels that are ``plant`` with a return no
    farther than ``BEHIND_TOLERANCE`` behind the farther of the two pieces'
    pixels nearest to them (pieces ``a``, ``b``; depth ``d``, NaN = none)."""
    near = []
    for m in (a, b):
        iy, ix = ndimage.distance_transform_edt(~m, return_indices=True)[1]
        near.append(d[iy[strip], ix[strip]])
    with np.errstate(invalid="ignore"):
        ok = plant[strip] & (d[strip] <= np.fmax(near[0], near[1]) + BEHIND_TOLERANCE)
    return float(ok.mean())


def JoinFruitFragments(class_map: np.ndarray, instance_map: np.ndarray, depth: np.ndarray,
                       K: Intrinsics, depth_jump: float = 0.02, max_gap: float = MAX_GAP,
                       max_extent: float = MAX_FRUIT_EXTENT) -> np.ndarray:
    """``instance_map`` (HxW int64, per-class index, -1 = none) with fruit
    instances that are fragments of one fruit (module docstring) joined,
    fruit instances renumbered by size (0 = largest); other classes
    unchanged. ``depth``: HxW m (NaN/inf/0 = no return), ``K`` its
    intrinsics."""
    cls = np.asarray(class_map)
    inst = np.asarray(instance_map, np.int64).copy()
    fruit = cls == FRUIT
    ids = np.unique(inst[fruit])
    ids = ids[ids >= 0]
    if len(ids) < 2:
        return inst
    d = np.where(ValidDepthMask(depth), np.asarray(depth, np.float64), np.nan)
    plant = (cls != BACKGROUND) & ~fruit
    group = {int(i): int(i) for i in ids}

    def root(i):
        while group[i] != i:
            i = group[i]
        return i
    lab = np.where(fruit, inst + 1, 0)
    boxes = ndimage.find_objects(lab)
    size = np.bincount(lab.ravel(), minlength=len(boxes) + 1)
    ids = np.array([i for i in ids if size[i + 1] >= MIN_FRAGMENT_PIXELS], np.int64)
    z = {int(i): _Median(d[boxes[i]], lab[boxes[i]] == i + 1) for i in ids}
    square = np.ones((3, 3), bool)
    H, W = cls.shape
    for i in ids:
        i = int(i)
        if not np.isfinite(z[i]):
            continue
        r = max(MIN_GAP_PX, int(np.ceil(max_gap * K.fx / z[i])))
        for j in ids[ids > i]:
            j = int(j)
            bi, bj = boxes[i], boxes[j]
            if (bj[0].start > bi[0].stop + r or bi[0].start > bj[0].stop + r
                    or bj[1].start > bi[1].stop + r or bi[1].start > bj[1].stop + r):
                continue                     # farther apart than the gap
            win = (slice(max(min(bi[0].start, bj[0].start) - r - 1, 0),
                         min(max(bi[0].stop, bj[0].stop) + r + 1, H)),
                   slice(max(min(bi[1].start, bj[1].start) - r - 1, 0),
                         min(max(bi[1].stop, bj[1].stop) + r + 1, W)))
            a, b = lab[win] == i + 1, lab[win] == j + 1
            grown_a = ndimage.binary_dilation(a, square, iterations=r)
            if not (grown_a & b).any():
                continue
            grown_b = ndimage.binary_dilation(b, square, iterations=r)
            # the strip: what closing the pair fills between them
            closed = ndimage.binary_closing(np.pad(a | b, r + 1), square, iterations=r)
            strip = closed[r + 1:-r - 1, r + 1:-r - 1] & ~(a | b) & grown_a & grown_b
            dw = d[win]
            za, zb = _Median(dw, a & grown_b), _Median(dw, b & grown_a)
            if not (np.isfinite(za) and np.isfinite(zb)) or abs(za - zb) > depth_jump:
                continue
            if strip.any() and _OccluderShare(strip, plant[win], dw, a, b) < STRIP_PLANT_SHARE:
                continue
            ri, rj = root(i), root(j)
            if ri == rj:
                continue
            union = np.isin(lab, [k + 1 for k in group if root(k) in (ri, rj)])
            if _Extent(DeprojectPixels(d, union, K)) > max_extent:
                continue
            group[max(ri, rj)] = min(ri, rj)
    roots = {k: root(k) for k in group}
    if len(set(roots.values())) == len(roots):
        return inst
    new_of = np.arange(-1, len(boxes), dtype=np.int64)   # lab value -> joined root
    for k, r in roots.items():
        new_of[k + 1] = r
    joined = np.where(fruit, new_of[lab], -1)
    rs, sizes = np.unique(joined[fruit & (joined >= 0)], return_counts=True)
    order = np.full(len(boxes) + 1, -1, np.int64)
    order[rs[np.argsort(-sizes, kind="stable")]] = np.arange(len(rs))
    inst[fruit] = np.where(joined[fruit] >= 0, order[np.maximum(joined[fruit], 0)], -1)
    return inst


def DropFruitSpecks(cls: np.ndarray, inst: np.ndarray, prob: np.ndarray, min_pixels: int,
                    depth: np.ndarray, fx: float, reach: float = MAX_FRUIT_EXTENT) -> bool:
    """Specks called fruit: fruit instances of fewer than ``min_pixels``
    pixels and farther than ``reach`` (m, in the image plane at their
    depth ``depth``, m; ``fx`` px) from every larger fruit instance (a
    part of a fruit lies within the fruit's length of its other parts: the
    one-leaf suite's heavy views show 20 pixels of a red fruit beyond a
    leaf's stripe) become, pixel by pixel, the most
    probable other class of ``prob`` (C x H x W class probabilities, ids as
    ``cls``'s); ``cls`` (H x W) changes in place, ``inst`` does not (the
    caller remakes it). True when any changed."""
    fruit = (cls == FRUIT) & (inst >= 0)
    if not fruit.any():
        return False
    ids, counts = np.unique(inst[fruit], return_counts=True)
    small = ids[counts < min_pixels]
    if not len(small):
        return False
    large = fruit & ~np.isin(inst, small)
    d_px = (ndimage.distance_transform_edt(~large) if large.any()
            else np.full(cls.shape, np.inf))
    speck = np.zeros(cls.shape, bool)
    for i in small:
        m = fruit & (inst == i)
        z = depth[m]
        z = z[np.isfinite(z) & (z > 0)]
        z = float(np.median(z)) if len(z) else np.inf      # no return: no fruit to be part of
        if not float(d_px[m].min()) * z / fx < reach:
            speck |= m
    if not speck.any():
        return False
    other = prob[:, speck].copy()
    other[FRUIT] = -1.0
    cls[speck] = other.argmax(0)
    return True
