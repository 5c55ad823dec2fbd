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
