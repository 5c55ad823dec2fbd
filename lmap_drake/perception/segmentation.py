"""Per-pixel semantic segmentation of an RGB-D view into background, branch,
leaf and fruit (ids from ``lmap_drake.labels``) with instance ids.

Five backends behind one interface (``Segmenter.Segment``), chosen by
``PerceptionConfig.segmenter``:

- ``segnet`` (the default): a small RGB-D U-Net trained here on randomised
  simulator renders (``lmap_drake/perception/segnet.py``,
  ``scripts/train_segnet.py``); no labels at run time, finds green fruit on
  green leaves from the depth's shape.
- ``label``: decodes the simulator's label image (exact; tests, ablations).
- ``color_depth``: classical, needs no labels or weights, works on real
  RGB-D. Colour (HSV) separates saturated red/orange/yellow fruit from green
  leaves; geometry finds the branch (thin, long, straight structures after a
  metric-size morphological opening of the plant mask split at depth
  discontinuities) and green fruit (curved, non-planar green regions).
- ``sam`` and ``grounded_sam``: foundation models from local files
  (``lmap_drake/perception/foundation.py``, the optional extra
  ``.[foundation]``): SAM prompted by segnet's (or color_depth's)
  instances, and GroundingDINO + SAM. Missing files raise
  ``MissingWeightsError`` naming the path and the config key; nothing is
  downloaded.

Every instance carries a confidence in [0, 1] (``Segmentation.confidence``,
keyed by (class id, instance index)): segnet's mean softmax probability of
the instance's class over its pixels, SAM's predicted mask IoU times its
prompt's, 1 for the labels; color_depth has no score model and gives none
(its instances are taken as what they are called).

Images: ``rgb`` HxWx3 (or x4) uint8, ``depth`` HxW float metres along the
optical axis (NaN/inf/0 = no return), ``label`` HxW render labels.
"""
from __future__ import annotations

import abc
import dataclasses as dc
import hashlib
from pathlib import Path

import numpy as np
from scipy import ndimage

from lmap_drake.errors import WeightsError
from lmap_drake.labels import (BACKGROUND, BRANCH, FRUIT, LEAF, ROBOT,
                               LeafBoundaryMask, OracleLabels)
from lmap_drake.perception.fruit_fragments import DropFruitSpecks, JoinFruitFragments
from lmap_drake.perception.leaf_boundaries import SplitRegionsAtNecks
from lmap_drake.perception.leaf_patches import FruitPatchesInLeaves, VetoLeafPatches
from lmap_drake.perception.points import Intrinsics, Neighbour, PointsImage, ValidDepthMask

SEGMENTERS = ("segnet", "color_depth", "label", "sam", "grounded_sam")
CLASS_IDS = {"branch": BRANCH, "leaf": LEAF, "fruit": FRUIT}


class SegmenterError(ValueError):
    """Bad segmenter name or missing input."""


class MissingWeightsError(WeightsError):
    """A model file named in the perception config does not exist."""


@dc.dataclass
class Segmentation:
    """``class_map`` HxW int64 (labels ids, 0 = background), ``instance_map``
    HxW int64 (per-class instance index, -1 = background), ``flags``,
    ``confidence`` {(class id, instance index): score in [0, 1]},
    ``leaf_boundary`` HxW bool where two leaves meet in the image (None: the
    backend does not say; ``perception.leaf_boundaries``)."""
    class_map: np.ndarray
    instance_map: np.ndarray
    flags: list[str] = dc.field(default_factory=list)
    confidence: dict = dc.field(default_factory=dict)
    leaf_boundary: np.ndarray | None = None

    def mask(self, class_id: int) -> np.ndarray:
        return self.class_map == class_id

    def Instances(self) -> list[tuple[int, int, int, float]]:
        """(class id, instance index, pixels, confidence) of every instance
        (confidence NaN where the backend gave none)."""
        out = []
        fg = self.class_map != BACKGROUND
        pairs, counts = np.unique(np.stack([self.class_map[fg], self.instance_map[fg]]),
                                  axis=1, return_counts=True)
        for (c, i), n in zip(pairs.T, counts):
            if i >= 0:
                out.append((int(c), int(i), int(n),
                            float(self.confidence.get((int(c), int(i)), np.nan))))
        return out


def InstanceConfidence(class_map: np.ndarray, instance_map: np.ndarray,
                       score: np.ndarray | float) -> dict:
    """{(class id, instance): mean of ``score`` (HxW, or a constant) over the
    instance's pixels}, rounded to 4 digits."""
    out = {}
    fg = (class_map != BACKGROUND) & (instance_map >= 0)
    if not fg.any():
        return out
    key = class_map[fg] * (int(instance_map.max()) + 1) + instance_map[fg]
    uniq, inv = np.unique(key, return_inverse=True)
    vals = np.broadcast_to(np.asarray(score, np.float64), class_map.shape)[fg]
    means = np.bincount(inv, weights=vals) / np.bincount(inv)
    stride = int(instance_map.max()) + 1
    for k, m in zip(uniq, means):
        out[(int(k // stride), int(k % stride))] = round(float(m), 4)
    return out


def _rgb3(rgb) -> np.ndarray:
    a = np.asarray(getattr(rgb, "data", rgb))
    return np.ascontiguousarray(a[..., :3]).astype(np.uint8)


def _depth2(depth) -> np.ndarray:
    d = np.asarray(getattr(depth, "data", depth), dtype=np.float64)
    return d[..., 0] if d.ndim == 3 else d


class Segmenter(abc.ABC):
    """Interface: ``Segment(rgb, depth, label=None) -> Segmentation``."""
    name = "base"
    needs_label = False

    @abc.abstractmethod
    def Segment(self, rgb, depth, label=None) -> Segmentation:
        """Per-pixel classes and instances of one RGB-D (+ label) frame."""


def InstancesFromComponents(class_map: np.ndarray, depth: np.ndarray | None = None,
                            depth_jump: float = 0.02, leaf_neck_ratio: float = 0.5,
                            leaf_boundary: np.ndarray | None = None) -> np.ndarray:
    """Per-class 8-connected components as instance ids (0 = largest);
    neighbouring pixels whose depth differs by more than ``depth_jump`` m are
    cut apart when ``depth`` is given, and a leaf region is cut where its
    outline narrows to a neck (``leaf_boundaries.SplitAtNecks`` at
    ``leaf_neck_ratio``; 0 = not): blades touching at one depth. Leaf pixels
    are also cut at ``leaf_boundary`` (HxW bool, the segmenter's leaf
    boundary band), which then joins its nearest instance."""
    inst = np.full(class_map.shape, -1, np.int64)
    cut = DepthEdges(depth, depth_jump, both_sides=True) if depth is not None else None
    for c in (BRANCH, LEAF, FRUIT):
        m = class_map == c
        cut_c = cut
        if c == LEAF and leaf_boundary is not None:
            cut_c = leaf_boundary if cut is None else cut | leaf_boundary
        if cut_c is not None:
            m = m & ~cut_c
        lab, n = ndimage.label(m, structure=np.ones((3, 3)))
        if n == 0:
            continue
        if c == LEAF and leaf_neck_ratio > 0:
            lab, n = SplitRegionsAtNecks(lab, n, leaf_neck_ratio)
        sizes = ndimage.sum(m, lab, index=np.arange(1, n + 1))
        order = np.argsort(-sizes, kind="stable")
        remap = np.full(n + 1, -1, np.int64)
        remap[order + 1] = np.arange(n)
        inst[m] = remap[lab[m]]
        if cut_c is not None:  # cut pixels join their nearest instance
            rest = (class_map == c) & cut_c
            if rest.any():
                _, (iy, ix) = ndimage.distance_transform_edt(~m, return_indices=True)
                inst[rest] = inst[iy[rest], ix[rest]]
    return inst


class LabelSegmenter(Segmenter):
    """Exact segmentation from the simulator's label image (robot pixels are
    background; the greenhouse's neighbouring plants leaf / branch with
    ``neighbours``, ``perception.label_neighbours``, else background)."""
    name = "label"
    needs_label = True

    def __init__(self, neighbours: bool = True):
        self.neighbours = bool(neighbours)

    def Segment(self, rgb, depth, label=None) -> Segmentation:
        if label is None:
            raise SegmenterError("the 'label' segmenter needs camera0.label_image "
                                 "(simulation only); connect it or choose color_depth")
        cls, inst = OracleLabels(np.asarray(getattr(label, "data", label)), self.neighbours)
        cls = np.where(cls == ROBOT, BACKGROUND, cls).astype(np.int64)
        inst = np.where(cls == BACKGROUND, -1, inst).astype(np.int64)
        return Segmentation(cls, inst, [], InstanceConfidence(cls, inst, 1.0),
                            LeafBoundaryMask(np.where(cls == LEAF, inst, -1)))


# ----------------------------------------------------------------------------
# Classical colour + depth segmenter.

@dc.dataclass
class ColorDepthParams:
    """Thresholds of ``ColorDepthSegmenter`` (hue in degrees, S and V in
    [0, 1], lengths in metres)."""
    depth_cut: float = 1.5
    fruit_hue_max: float = 65.0      # red/orange/yellow: hue < max or >= wrap
    fruit_hue_wrap: float = 330.0
    fruit_min_saturation: float = 0.75
    green_hue: tuple[float, float] = (65.0, 170.0)
    plant_min_saturation: float = 0.2
    min_value: float = 0.08
    depth_edge: float = 0.01         # depth jump that separates surfaces
    branch_max_width: float = 0.035  # opening size: wider structures are not branch
    branch_min_length: float = 0.04
    branch_max_aspect: float = 0.35  # width / length of a branch piece
    detect_green_fruit: bool = True
    green_fruit_min_relief: float = 0.3  # sqrt(l3 / l2) of a region's points
    green_fruit_max_extent: float = 0.16
    min_region_pixels: int = 30
    fill_iterations: int = 3


def RgbToHsv(rgb: np.ndarray) -> np.ndarray:
    """HxWx3 uint8 -> HxWx3 float (hue degrees, saturation, value)."""
    from matplotlib.colors import rgb_to_hsv
    hsv = rgb_to_hsv(rgb.astype(np.float64) / 255.0)
    hsv[..., 0] *= 360.0
    return hsv


def DepthEdges(depth: np.ndarray, jump: float, both_sides: bool = False) -> np.ndarray:
    """Pixels on the far side of a depth discontinuity larger than ``jump`` m
    with a 4-neighbour (both sides if ``both_sides``). Invalid depth never
    makes an edge."""
    d = np.where(ValidDepthMask(depth), depth, np.nan)
    edge = np.zeros(d.shape, bool)
    with np.errstate(invalid="ignore"):
        for axis in (0, 1):
            diff = np.diff(d, axis=axis)  # d[i+1] - d[i]
            far_next = diff > jump        # i+1 is farther
            far_prev = diff < -jump       # i is farther
            if both_sides:
                far_next = far_prev = far_next | far_prev
            if axis == 0:
                edge[1:] |= far_next
                edge[:-1] |= far_prev
            else:
                edge[:, 1:] |= far_next
                edge[:, :-1] |= far_prev
    return edge


def _opening(mask: np.ndarray, radius: float) -> np.ndarray:
    """Binary opening with a disk of ``radius`` px via distance transforms."""
    if radius <= 0.5 or not mask.any():
        return mask.copy()
    eroded = ndimage.distance_transform_edt(mask) > radius
    if not eroded.any():
        return eroded
    return (ndimage.distance_transform_edt(~eroded) <= radius) & mask


def _pca(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (descending) and eigenvectors (columns) of the covariance."""
    c = np.cov(points.T)
    w, v = np.linalg.eigh(c)
    return w[::-1].clip(min=0), v[:, ::-1]


class ColorDepthSegmenter(Segmenter):
    """Classical RGB-D segmenter: no labels, no weights.

    1. Plant pixels: valid depth within the cut and a saturated colour (grey,
       white, black and blue — the robot, the background — are not plant).
    2. Far-side pixels of depth discontinuities are set aside so surfaces at
       different depths (a branch behind a leaf) are not connected.
    3. Branch: the plant mask minus its opening with a disk as wide as
       ``branch_max_width`` at the plant's depth leaves thin structures; each
       thin 8-connected piece that is not fruit-coloured and whose
       back-projected points are long (>= ``branch_min_length``) and narrow
       (width/length <= ``branch_max_aspect``) is branch (green or brown).
    4. Fruit: saturated red/orange/yellow; leaf: green. A green region whose
       points are far from planar (relief sqrt(l3/l2) >= ``green_fruit_min_relief``)
       and fruit-sized is a green fruit (flag ``green_fruit_detected``).
    5. Unassigned pixels next to a labelled pixel at a similar depth (shaded
       rims, discontinuity pixels) take its class, for a few iterations.
    6. Instances: per-class connected components cut at depth jumps.
    """
    name = "color_depth"

    def __init__(self, K: Intrinsics, params: ColorDepthParams | None = None):
        self.K = K
        self.p = params or ColorDepthParams()

    def ColorMasks(self, rgb: np.ndarray, valid: np.ndarray):
        """(fruit-coloured, green, other plant-coloured) boolean masks."""
        p = self.p
        hsv = RgbToHsv(rgb)
        h, s, v = hsv[..., 0], hsv[..., 1], hsv[..., 2]
        lit = valid & (v >= p.min_value)
        warm = (h < p.fruit_hue_max) | (h >= p.fruit_hue_wrap)
        fruit = lit & warm & (s >= p.fruit_min_saturation)
        green = lit & (h >= p.green_hue[0]) & (h < p.green_hue[1]) & (s >= p.plant_min_saturation)
        other = lit & warm & (s >= p.plant_min_saturation) & ~fruit
        return fruit, green, other

    def Segment(self, rgb, depth, label=None) -> Segmentation:
        p = self.p
        rgb = _rgb3(rgb)
        d = _depth2(depth)
        flags: list[str] = []
        valid = ValidDepthMask(d, p.depth_cut)
        cls = np.zeros(d.shape, np.int64)
        if not valid.any():
            return Segmentation(cls, np.full(d.shape, -1, np.int64), ["no_valid_depth"])
        P_img = PointsImage(d, self.K)
        fruit_col, green, other = self.ColorMasks(rgb, valid)
        plant = fruit_col | green | other
        edges = DepthEdges(d, p.depth_edge)
        core = plant & ~edges

        # Branch: thin, long, straight pieces.
        branch = np.zeros_like(core)
        if core.any():
            z = float(np.median(d[core]))
            radius = 0.5 * p.branch_max_width * self.K.fx / z
            thin = core & ~_opening(core, radius) & ~fruit_col
            lab, n = ndimage.label(thin, structure=np.ones((3, 3)))
            for i, sl in enumerate(ndimage.find_objects(lab), start=1):
                piece = lab[sl] == i
                if piece.sum() < p.min_region_pixels:
                    continue
                pts = P_img[sl][piece]
                w, _ = _pca(pts)
                length = 4.0 * np.sqrt(w[0])  # +-2 sigma of a uniform-ish spread
                width = 4.0 * np.sqrt(w[1])
                if length >= p.branch_min_length and width <= p.branch_max_aspect * length:
                    branch[sl] |= piece
        cls[branch] = BRANCH
        cls[core & ~branch & fruit_col] = FRUIT
        cls[core & ~branch & green] = LEAF

        # Green fruit: curved, fruit-sized green regions.
        if p.detect_green_fruit:
            lab, n = ndimage.label(cls == LEAF)
            for i, sl in enumerate(ndimage.find_objects(lab), start=1):
                region = lab[sl] == i
                if region.sum() < 4 * p.min_region_pixels:
                    continue
                pts = P_img[sl][region]
                w, _ = _pca(pts)
                relief = np.sqrt(w[2] / max(w[1], 1e-12))
                extent = 4.0 * np.sqrt(w[0])
                if relief >= p.green_fruit_min_relief and extent <= p.green_fruit_max_extent:
                    cls[sl][region] = FRUIT
                    if "green_fruit_detected" not in flags:
                        flags.append("green_fruit_detected")

        # Fill rims and discontinuity pixels from depth-continuous neighbours.
        todo = valid & (cls == BACKGROUND) & (plant | edges)
        tol = max(p.depth_edge, 1e-3)
        for _ in range(p.fill_iterations):
            if not todo.any():
                break
            new = cls.copy()
            for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (-1, -1), (1, -1), (-1, 1)):
                src, srcd = Neighbour(cls, dy, dx, 0), Neighbour(d, dy, dx, np.nan)
                with np.errstate(invalid="ignore"):
                    ok = todo & (new == BACKGROUND) & (src != BACKGROUND) & (np.abs(srcd - d) < tol)
                new[ok] = src[ok]
            todo &= new == BACKGROUND
            cls = new
            # the fill may grow from any plant pixel, including the edges
        inst = InstancesFromComponents(cls, d, max(2 * p.depth_edge, 0.02))
        return Segmentation(cls, inst, flags)      # no score model: no confidence


def SnapFruitToDepthEdges(cls: np.ndarray, depth: np.ndarray, front: float = 0.01,
                          continuity: float = 0.006, iterations: int = 4) -> np.ndarray:
    """Fruit pixels that continue a neighbouring leaf surface (4-neighbour
    depth within ``continuity`` m) and lie more than ``front`` m in front of
    their fruit region's median depth become leaf, a few pixels deep: the
    fruit-leaf border moves to the depth edge where the leaf's rim crosses
    the fruit. A network's border is a pixel or two off, and on a fruit of
    which only a few dozen pixels show, leaf pixels called fruit put fruit
    points centimetres in front of the fruit."""
    cls = cls.copy()
    d = np.where(ValidDepthMask(depth), np.asarray(depth, np.float64), np.nan)
    fruit = cls == FRUIT
    if not fruit.any() or not (cls == LEAF).any():
        return cls
    lab, n = ndimage.label(fruit, structure=np.ones((3, 3)))
    med = ndimage.median(np.nan_to_num(d, nan=0.0), lab, index=np.arange(1, n + 1))
    cnt = ndimage.sum(np.isfinite(d) & fruit, lab, index=np.arange(1, n + 1))
    med = np.where(np.asarray(cnt) > 0, med, np.nan)
    ahead = np.zeros(cls.shape, bool)
    with np.errstate(invalid="ignore"):
        ahead[fruit] = d[fruit] < np.asarray(med)[lab[fruit] - 1] - front
    for _ in range(iterations):
        leaf = cls == LEAF
        flip = np.zeros(cls.shape, bool)
        for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
            nb_leaf, nb_d = Neighbour(leaf, dy, dx, False), Neighbour(d, dy, dx, np.nan)
            with np.errstate(invalid="ignore"):
                flip |= ahead & (cls == FRUIT) & nb_leaf & (np.abs(nb_d - d) < continuity)
        if not flip.any():
            break
        cls[flip] = LEAF
    return cls


class SegNetSegmenter(Segmenter):
    """The trained RGB-D network (``lmap_drake.perception.segnet``) on the
    bounding box of the returns within the depth cut; everything outside it,
    and every return beyond the cut, is background; the fruit-leaf border
    snapped to the depth edge (``SnapFruitToDepthEdges``); a fruit instance
    lying in a leaf's surface gets confidence 0 (``VetoLeafPatches``, with
    ``leaf_patches``). Instances:
    per-class connected components cut at depth jumps, fruit fragments
    split by a thin occluder joined (``fruit_fragments.JoinFruitFragments``)."""
    name = "segnet"

    # Results kept for the last few images (by content): the episode's
    # figures segment the views the pipeline has already segmented (0.6 s
    # a view on one core).
    KEEP = 4

    def __init__(self, K: Intrinsics, weights_file: str | Path, depth_cut: float = 1.5,
                 device: str = "cpu", leaf_patches: bool = True, min_fruit_pixels: int = 0):
        from lmap_drake.perception.segnet import LoadSegNet
        self.K, self.depth_cut, self.device = K, float(depth_cut), device
        self.leaf_patches, self.min_fruit_pixels = bool(leaf_patches), int(min_fruit_pixels)
        self.net = LoadSegNet(weights_file, device)
        self._kept: list[tuple[bytes, Segmentation]] = []

    def Segment(self, rgb, depth, label=None) -> Segmentation:
        rgb = _rgb3(rgb)
        d = _depth2(depth)
        key = hashlib.sha1(np.asarray(rgb.shape + d.shape, np.int64).tobytes()
                           + rgb.tobytes() + np.ascontiguousarray(d).tobytes()).digest()
        for k, seg in self._kept:
            if k == key:
                return _CopySegmentation(seg)
        seg = self._Segment(rgb, d)
        self._kept = ([(key, _CopySegmentation(seg))] + self._kept)[:self.KEEP]
        return seg

    def _Segment(self, rgb: np.ndarray, d: np.ndarray) -> Segmentation:
        from lmap_drake.perception.segnet import NUM_CLASSES, CropBox, PredictLogits, SegNetInputs
        cls = np.zeros(d.shape, np.int64)
        valid = ValidDepthMask(d, self.depth_cut)
        box = CropBox(valid, 16)
        if box is None:
            return Segmentation(cls, np.full(d.shape, -1, np.int64), ["no_valid_depth"])
        x = SegNetInputs(rgb, d, self.K, self.depth_cut)
        out = PredictLogits(self.net, x[:, box[0], box[1]], self.device)
        logits = out[:NUM_CLASSES]
        cls[box] = logits.argmax(0)
        with np.errstate(invalid="ignore"):
            cls[np.isfinite(d) & (d > self.depth_cut)] = BACKGROUND
        cls = SnapFruitToDepthEdges(cls, d)
        boundary = None
        if len(out) > NUM_CLASSES:   # the boundary head: logit > 0 is probability > 0.5
            boundary = np.zeros(d.shape, bool)
            boundary[box] = out[NUM_CLASSES] > 0.0
            boundary &= cls == LEAF
        e = np.exp(logits - logits.max(0))
        prob = np.zeros((len(e),) + d.shape)
        prob[:, box[0], box[1]] = e / e.sum(0)

        def instances(cls):
            return JoinFruitFragments(cls, InstancesFromComponents(cls, d, 0.02,
                                                                   leaf_boundary=boundary),
                                      d, self.K, 0.02)
        inst = instances(cls)
        if self.min_fruit_pixels > 0 and DropFruitSpecks(cls, inst, prob, self.min_fruit_pixels,
                                                          d, self.K.fx):
            inst = instances(cls)
        p_cls = np.take_along_axis(prob, cls[None], 0)[0]  # probability of the class given
        conf, flags = InstanceConfidence(cls, inst, p_cls), []
        if self.leaf_patches:
            flags = VetoLeafPatches(conf, cls, inst, FruitPatchesInLeaves(cls, d))
        return Segmentation(cls, inst, flags, conf, boundary)


def _CopySegmentation(seg: Segmentation) -> Segmentation:
    return Segmentation(seg.class_map.copy(), seg.instance_map.copy(), list(seg.flags),
                        dict(seg.confidence),
                        None if seg.leaf_boundary is None else seg.leaf_boundary.copy())


def MakeSegmenter(cfg, K: Intrinsics) -> Segmenter:
    """The backend named by ``cfg.segmenter`` (a ``PerceptionConfig``)."""
    name = cfg.segmenter
    if name == "label":
        return LabelSegmenter(cfg.label_neighbours)
    if name == "color_depth":
        params = ColorDepthParams(depth_cut=cfg.depth_cut)
        for f in ("branch_max_width", "detect_green_fruit"):
            if hasattr(cfg, f):
                setattr(params, f, getattr(cfg, f))
        return ColorDepthSegmenter(K, params)
    if name in ("sam", "grounded_sam"):
        from lmap_drake.perception import foundation  # cycle: it builds on this module
        if name == "sam":
            return foundation.SamSegmenter(cfg, K)
        return foundation.GroundedSamSegmenter(cfg)
    if name == "segnet":
        from lmap_drake.paths import REPO_ROOT
        path = Path(cfg.segnet_weights)
        return SegNetSegmenter(K, path if path.is_absolute() else REPO_ROOT / path,
                               cfg.depth_cut, cfg.segnet_device,
                               getattr(cfg, "fruit_leaf_patches", True),
                               getattr(cfg, "min_fruit_pixels", 0))
    raise SegmenterError(f"perception.segmenter '{name}' unknown; choose one of "
                         f"{', '.join(SEGMENTERS)}")


def ClassIou(pred: np.ndarray, truth: np.ndarray, class_id: int) -> float:
    """Intersection over union of one class; NaN when both are empty."""
    a, b = pred == class_id, truth == class_id
    union = np.logical_or(a, b).sum()
    if union == 0:
        return float("nan")
    return float(np.logical_and(a, b).sum() / union)


def FruitInstanceTruth(seg: Segmentation, truth: np.ndarray, min_pixels: int = 50) -> list[dict]:
    """Every fruit instance of ``seg`` with at least ``min_pixels`` pixels:
    its pixel count and the fractions of its pixels that the truth class
    map ``truth`` calls fruit, branch and leaf. An instance mostly not
    fruit (``fruit`` < 0.5) is a phantom: the planner would complete and
    reveal a fruit that is not there."""
    out = []
    fruit = seg.class_map == FRUIT
    ids, counts = np.unique(seg.instance_map[fruit], return_counts=True)
    for i, n in zip(ids, counts):
        if i < 0 or n < min_pixels:
            continue
        t = truth[fruit & (seg.instance_map == i)]
        known = getattr(seg, "confidence", None) or {}
        conf = known.get((FRUIT, int(i)), np.nan)
        out.append({"pixels": int(n), "fruit": round(float(np.mean(t == FRUIT)), 3),
                    "confidence": None if np.isnan(conf) else round(float(conf), 4),
                    "branch": round(float(np.mean(t == BRANCH)), 3),
                    "leaf": round(float(np.mean(t == LEAF)), 3)})
    return out


def TruthClassMap(label) -> np.ndarray:
    """Ground-truth class map from a render label image (robot and the
    neighbouring plants = background: evaluations leave the neighbours'
    pixels out, training adds them from ``labels.NeighbourClassMap``)."""
    return LabelSegmenter(neighbours=False).Segment(None, None, label).class_map
