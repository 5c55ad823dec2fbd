import numpy as np
import pytest

from lmap_drake.labels import BACKGROUND, FRUIT, LEAF, DecodeLabels, EncodeLabel


def test_encode_decode_round_trip():
    img = np.array([[EncodeLabel(FRUIT, 3), EncodeLabel(LEAF, 0), 32766, 5]], np.int16)
    cls, inst = DecodeLabels(img)
    assert cls.tolist() == [[FRUIT, LEAF, BACKGROUND, BACKGROUND]]
    assert inst.tolist() == [[3, 0, -1, -1]]


def test_encode_rejects_bad_values():
    with pytest.raises(ValueError):
        EncodeLabel(FRUIT, 100)
    with pytest.raises(ValueError):
        EncodeLabel(BACKGROUND)


def test_neighbour_labels_are_background_to_decode_and_classes_to_neighbour_map():
    from lmap_drake.labels import BRANCH, EncodeNeighbourLabel, NeighbourClassMap
    img = np.array([[EncodeNeighbourLabel(LEAF), EncodeNeighbourLabel(BRANCH),
                     EncodeLabel(LEAF, 99), 0]], np.int16)
    cls, inst = DecodeLabels(img)
    assert cls.tolist() == [[BACKGROUND, BACKGROUND, LEAF, BACKGROUND]]
    assert inst[0, :2].tolist() == [-1, -1]
    assert NeighbourClassMap(img).tolist() == [[LEAF, BRANCH, BACKGROUND, BACKGROUND]]
    with pytest.raises(ValueError):
        EncodeNeighbourLabel(FRUIT)


def test_oracle_labels_see_the_neighbouring_row_only_when_asked():
    """``OracleLabels(neighbours=True)``: the neighbouring plants' leaf and
    branch pixels take their class, each 8-connected region its own
    instance from NEIGHBOUR_INSTANCE on; the worked plant's pixels are
    unchanged; without it, ``DecodeLabels``."""
    from lmap_drake.labels import (BRANCH, NEIGHBOUR_INSTANCE, EncodeNeighbourLabel,
                                   OracleLabels)
    nl, nb = EncodeNeighbourLabel(LEAF), EncodeNeighbourLabel(BRANCH)
    img = np.array([[nl, nl, 0, nl, EncodeLabel(LEAF, 4)],
                    [nb, 0, 0, 0, EncodeLabel(FRUIT, 1)]], np.int16)
    cls, inst = OracleLabels(img)
    assert (cls == DecodeLabels(img)[0]).all() and (inst == DecodeLabels(img)[1]).all()
    cls, inst = OracleLabels(img, neighbours=True)
    assert cls.tolist() == [[LEAF, LEAF, BACKGROUND, LEAF, LEAF], [BRANCH, 0, 0, 0, FRUIT]]
    assert inst[0, 0] == inst[0, 1] >= NEIGHBOUR_INSTANCE      # one region
    assert inst[0, 3] >= NEIGHBOUR_INSTANCE and inst[0, 3] != inst[0, 0]   # another
    assert inst[1, 0] >= NEIGHBOUR_INSTANCE
    assert inst[0, 4] == 4 and inst[1, 4] == 1 and inst[0, 2] == -1


def test_leaf_boundary_band_lies_where_two_leaves_meet_and_nowhere_else():
    from lmap_drake.labels import LeafBoundaryMask
    ids = np.full((20, 30), -1)
    ids[5:15, 2:15] = 0
    ids[5:15, 15:28] = 1           # flush against leaf 0 along column 15
    band = LeafBoundaryMask(ids, radius=2)
    assert band[5:15, 13:17].all()                       # two pixels either side of the seam
    assert not band[:, :13].any() and not band[:, 17:].any()
    assert not band[ids < 0].any()                       # never off a leaf
    one = np.where(ids >= 0, 0, -1)
    assert not LeafBoundaryMask(one).any()               # one leaf: no band along its outline
