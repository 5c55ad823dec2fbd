"""Layout helpers for the episode pictures on dense plants (image pixels:
u right, v down): instance outlines, label boxes placed apart from each
other, and the ground-truth focus of a simulated view (the target fruits
and the leaves that hide them)."""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from lmap_drake.labels import FRUIT, LEAF, DecodeLabels

CHAR_W, LINE_H = 6, 11          # PIL's default bitmap font, px
RADII = (8, 22, 40, 60, 85, 115, 150, 190)     # px, label distances tried in turn
FOCUS_FRUIT = (255, 0, 200)
FOCUS_LEAF_COLORS = [(255, 140, 0), (0, 230, 255), (255, 255, 255), (170, 120, 255)]


def InstanceEdges(class_map: np.ndarray, instance_map: np.ndarray) -> np.ndarray:
    """Pixels of a segmented instance with a 4-neighbour of another
    (class, instance): the outline of every instance, where touching leaves
    meet included."""
    key = np.asarray(class_map, np.int64) * 100003 + np.asarray(instance_map, np.int64)
    out = np.zeros(key.shape, bool)
    for axis in (0, 1):
        d = np.diff(key, axis=axis) != 0
        if axis == 0:
            out[1:] |= d
            out[:-1] |= d
        else:
            out[:, 1:] |= d
            out[:, :-1] |= d
    return out & (np.asarray(class_map) > 0)


def Outline(mask: np.ndarray, width: int = 2) -> np.ndarray:
    """The ``width``-pixel inner rim of ``mask``."""
    return mask & ~ndimage.binary_erosion(mask, iterations=max(1, width))


def TextBox(text: str) -> tuple[int, int]:
    """(width, height) px of a one-line label box in PIL's default font."""
    return CHAR_W * len(text) + 6, LINE_H + 3


def _Overlap(a, b) -> float:
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    return max(w, 0) * max(h, 0)


def PlaceLabels(anchors, sizes, shape, taken=()) -> list[tuple[int, int]]:
    """Top-left corners (u, v px) for label boxes of ``sizes`` (w, h px)
    near ``anchors`` (u, v px), in order: the first of 64 candidate spots
    around its anchor (right, left, above, below, the diagonals, at eight
    growing distances) that stays inside an image of ``shape`` (H, W) and overlaps
    no box placed before it nor ``taken`` (boxes u0, v0, u1, v1); the least
    overlapping spot if every one does."""
    H, W = shape[:2]
    boxes = [tuple(b) for b in taken]
    out = []
    for (u, v), (w, h) in zip(anchors, sizes):
        best, best_cost = None, np.inf
        for r in RADII:
            for du, dv in ((r, -h // 2), (-r - w, -h // 2), (-w // 2, -r - h), (-w // 2, r),
                           (r, -r - h), (-r - w, -r - h), (r, r), (-r - w, r)):
                x0 = int(np.clip(u + du, 0, max(W - w, 0)))
                y0 = int(np.clip(v + dv, 0, max(H - h, 0)))
                box = (x0, y0, x0 + w, y0 + h)
                cost = sum(_Overlap(box, b) for b in boxes)
                if cost < best_cost:
                    best, best_cost = box, cost
                if cost == 0:
                    break
            if best_cost == 0:
                break
        boxes.append(best)
        out.append(best[:2])
    return out


def GroundTruthFocus(label_image: np.ndarray, fruits: dict) -> list[dict]:
    """The focus of a simulated view from its label image: per target fruit
    ``i`` of ``fruits`` (fruit index -> its occluding leaf indices, most
    hiding first) the fruit's mask and text, then each occluder's mask and
    text (``leaf j hides fruit i``), each with a colour; a leaf hiding two
    targets is listed once. Instances not in the view are left out."""
    cls, inst = DecodeLabels(np.asarray(label_image))
    out, seen = [], set()
    for i, occluders in fruits.items():
        m = (cls == FRUIT) & (inst == i)
        if m.any():
            out.append({"mask": m, "text": f"target fruit {i}", "color": FOCUS_FRUIT,
                        "kind": "fruit"})
        for j in occluders:
            if j in seen:
                continue
            m = (cls == LEAF) & (inst == j)
            if m.any():
                seen.add(j)
                color = FOCUS_LEAF_COLORS[(len(seen) - 1) % len(FOCUS_LEAF_COLORS)]
                out.append({"mask": m, "text": f"leaf {j} (hides fruit {i})", "color": color,
                            "kind": "leaf"})
    return out


def PointsBox(uv, shape, pad: int = 2) -> tuple | None:
    """The box (u0, v0, u1, v1 px) around the finite image points ``uv``
    (N x 2) inside an image of ``shape`` (H, W), or None without any."""
    uv = np.asarray(uv, float).reshape(-1, 2)
    H, W = shape[:2]
    ok = np.all(np.isfinite(uv), axis=1)
    uv = uv[ok]
    uv = uv[(uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)]
    if not len(uv):
        return None
    lo, hi = uv.min(axis=0) - pad, uv.max(axis=0) + pad
    return (int(lo[0]), int(lo[1]), int(hi[0]) + 1, int(hi[1]) + 1)


def MaskBox(mask: np.ndarray) -> tuple | None:
    """The box (u0, v0, u1, v1 px) around ``mask``'s pixels, or None."""
    v, u = np.nonzero(mask)
    return PointsBox(np.c_[u, v], mask.shape, 0) if len(u) else None


def MaskAnchor(mask: np.ndarray) -> tuple[float, float]:
    """A pixel (u, v) inside ``mask``: its interior point farthest from the rim."""
    d = ndimage.distance_transform_edt(np.pad(mask, 1))[1:-1, 1:-1]
    v, u = np.unravel_index(int(np.argmax(d)), d.shape)
    return float(u), float(v)
