"""Semantic classes and the render-label encoding shared by the simulator,
perception and evaluation.

A render label is ``class_id * 100 + instance`` (instance 0..99); anything
outside [100, 500) is background (Drake's reserved empty/don't-care labels
included). A neighbouring plant (the greenhouse's next plants in the row
and behind it, not the plant being worked on) is ``NEIGHBOUR + class_id``
(``EncodeNeighbourLabel``): background to ``DecodeLabels`` (scoring,
occluders), its branch / leaf class to ``NeighbourClassMap`` (segmenter
training, and the pixels evaluation leaves out) and to the label oracle
(``OracleLabels``, ``perception.label_neighbours``).
"""
from __future__ import annotations

import numpy as np

BACKGROUND = 0
BRANCH = 1
LEAF = 2
FRUIT = 3
ROBOT = 4
CLASS_NAMES = {BACKGROUND: "background", BRANCH: "branch", LEAF: "leaf",
               FRUIT: "fruit", ROBOT: "robot"}
_STRIDE = 100
NEIGHBOUR = 900


def EncodeLabel(class_id: int, instance: int = 0) -> int:
    """Render-label value for a class and an instance index (0..99)."""
    if class_id not in CLASS_NAMES or class_id == BACKGROUND:
        raise ValueError(f"class_id must be one of {sorted(CLASS_NAMES)[1:]}, got {class_id}")
    if not 0 <= instance < _STRIDE:
        raise ValueError(f"instance must be in [0, {_STRIDE}), got {instance}")
    return class_id * _STRIDE + instance


def DecodeLabels(label_image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel (class_id, instance) arrays from a label image (any int dtype).

    Background pixels get class 0 and instance -1.
    """
    lab = np.asarray(label_image).astype(np.int64)
    if lab.ndim == 3:
        lab = lab[..., 0]
    valid = (lab >= _STRIDE) & (lab < (ROBOT + 1) * _STRIDE)
    cls = np.where(valid, lab // _STRIDE, BACKGROUND)
    inst = np.where(valid, lab % _STRIDE, -1)
    return cls, inst


# The label oracle's instance ids of the neighbouring plants' pixels start
# here (the worked plant's are 0..99).
NEIGHBOUR_INSTANCE = _STRIDE


def OracleLabels(label_image: np.ndarray, neighbours: bool = False
                 ) -> tuple[np.ndarray, np.ndarray]:
    """``DecodeLabels``; with ``neighbours`` the neighbouring plants'
    pixels are their class (branch / leaf) too, each 8-connected region of
    them one instance from ``NEIGHBOUR_INSTANCE`` on (the render does not
    tell their leaves apart): what a perfect segmenter sees."""
    cls, inst = DecodeLabels(label_image)
    if neighbours:
        from scipy import ndimage
        nb = NeighbourClassMap(label_image)
        for c in (BRANCH, LEAF):
            lab, _ = ndimage.label(nb == c, structure=np.ones((3, 3)))
            m = lab > 0
            cls[m], inst[m] = c, NEIGHBOUR_INSTANCE + lab[m] - 1
    return cls, inst


def EncodeNeighbourLabel(class_id: int) -> int:
    """Render-label value of a neighbouring plant's branch or leaf."""
    if class_id not in (BRANCH, LEAF):
        raise ValueError(f"a neighbouring plant's class_id must be {BRANCH} or {LEAF}, "
                         f"got {class_id}")
    return NEIGHBOUR + class_id


def NeighbourClassMap(label_image: np.ndarray) -> np.ndarray:
    """Per-pixel class id (branch / leaf) of the neighbouring plants' pixels
    of a label image; 0 elsewhere."""
    lab = np.asarray(label_image).astype(np.int64)
    if lab.ndim == 3:
        lab = lab[..., 0]
    return np.where((lab == NEIGHBOUR + BRANCH) | (lab == NEIGHBOUR + LEAF), lab - NEIGHBOUR,
                    BACKGROUND)


def LeafBoundaryMask(leaf_id: np.ndarray, radius: int = 2) -> np.ndarray:
    """HxW bool: leaf pixels (``leaf_id`` >= 0, one id per leaf, -1 = not a
    leaf) with a pixel of another leaf within ``radius`` pixels (Chebyshev):
    a band about ``2 * radius`` pixels wide along every border where two
    leaves meet in the image, whatever their depths (flush blades
    included), and nowhere inside a leaf or along its border with anything
    but a leaf."""
    from scipy import ndimage
    ids = np.asarray(leaf_id, np.int64)
    leaf = ids >= 0
    if not leaf.any():
        return np.zeros(ids.shape, bool)
    size = 2 * int(radius) + 1
    big = int(ids.max()) + 1
    hi = ndimage.grey_dilation(np.where(leaf, ids, -1), size=(size, size))
    lo = -ndimage.grey_dilation(np.where(leaf, -ids, -big), size=(size, size))
    return leaf & ((hi != ids) | (lo != ids))


def TrueLeafIds(label_image: np.ndarray) -> np.ndarray:
    """HxW int64 leaf identity from a render label image: the worked plant's
    leaf instance index, ``NEIGHBOUR + LEAF`` for every neighbouring-plant
    leaf (one id for all of them: the render does not tell them apart), -1
    elsewhere."""
    cls, inst = DecodeLabels(label_image)
    out = np.where(cls == LEAF, inst, -1)
    return np.where(NeighbourClassMap(label_image) == LEAF, NEIGHBOUR + LEAF, out)
