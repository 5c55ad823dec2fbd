"""The hinge study's rows (``studies.hinge.HingeRows``) on made-up leaves."""
import numpy as np

from lmap_drake.deformation.config import DeformationConfig
from lmap_drake.studies.hinge import HingeRows, Summary


def _Blade(x0, z_top, length=0.1, width=0.04, step=0.003):
    s, v = np.meshgrid(np.arange(0, length, step), np.arange(-width / 2, width / 2, step))
    return np.c_[x0 + 0 * s.ravel(), v.ravel(), z_top - s.ravel()]


def test_rows_match_instances_to_true_leaves_and_say_whether_the_error_is_covered():
    z = np.arange(0.0, 0.8, 0.002)
    stem = np.c_[np.zeros_like(z), np.zeros_like(z), z]
    near = _Blade(0.01, 0.45)          # 1 cm from the stem, attached at its top
    far = _Blade(0.06, 0.30)           # 6 cm from the stem: a long unseen petiole
    attach = [[0.0, 0.0, 0.45], [0.0, 0.0, 0.40]]   # 10 cm above the far one's top
    rows = HingeRows([near, far, _Blade(0.5, 0.5)], [stem] * 3, attach, [near, far],
                     DeformationConfig(), hinge_error=0.03)
    assert [r["true_leaf"] for r in rows] == [0, 1, None]
    assert rows[0]["error_cm"] < 1.5 and rows[0]["covered"]
    assert rows[1]["assumed_error_cm"] == rows[1]["unseen_petiole_cm"] > 5.9
    assert rows[1]["error_cm"] > 9.9 and not rows[1]["covered"]
    s = Summary(rows)
    assert s["matched"]["instances"] == 2 and s["unmatched"] == 1
    assert s["matched"]["covered"] == 0.5
