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
