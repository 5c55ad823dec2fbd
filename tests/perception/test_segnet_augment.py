"""The segmenter training's colour jitter (hue shift about the grey axis,
gain, white balance, blur, noise) and the greenhouse fraction's check."""
import numpy as np
import pytest

from lmap_drake.errors import InputError
from lmap_drake.perception.training import ColorJitter, HueRotation
from lmap_drake.studies.segnet_data import MakeSegNetData


def test_hue_rotation_keeps_grey_and_turns_red_toward_green():
    assert np.allclose(HueRotation(10.0) @ [0.4, 0.4, 0.4], 0.4)
    assert np.allclose(HueRotation(120.0) @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-9)
    r = HueRotation(10.0) @ [0.8, 0.1, 0.1]
    assert r[1] > 0.1 > r[2]                      # a small shift: still red, a little yellower


def test_color_jitter_stays_in_range_and_varies():
    x = np.random.default_rng(0).random((3, 32, 32)).astype(np.float32)
    outs = [ColorJitter(x, np.random.default_rng(k)) for k in range(8)]
    assert all(o.dtype == np.float32 and o.min() >= 0.0 and o.max() <= 1.0 for o in outs)
    assert len({round(float(o.mean()), 4) for o in outs}) == 8


def test_greenhouse_fraction_outside_0_1_is_refused(tmp_path):
    with pytest.raises(InputError, match="--greenhouse"):
        MakeSegNetData(tmp_path / "d", count=1, greenhouse=1.5)
    assert not (tmp_path / "d").exists()
