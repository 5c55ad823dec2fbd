"""Where the leaf is estimated to join its branch (``EstimateHinge``)."""
import numpy as np
from scipy.spatial import cKDTree

from lmap_drake.planning.attachment import BladeEnds, EstimateHinge


def _Stem(z0=0.0, z1=0.8, step=0.002):
    z = np.arange(z0, z1, step)
    return np.c_[np.zeros_like(z), np.zeros_like(z), z]


def _Blade(x_top, x_bottom, z_top, length=0.12, width=0.05, step=0.003):
    """A flat blade in a plane of constant y, hanging from z_top down by
    ``length``, its distance to the stem (x) going from x_top to x_bottom."""
    s, v = np.meshgrid(np.arange(0, length, step), np.arange(-width / 2, width / 2, step))
    s, v = s.ravel(), v.ravel()
    x = x_top + (x_bottom - x_top) * s / length
    return np.c_[x, v, z_top - s]


def test_a_leaf_hanging_along_its_stem_hinges_at_its_upper_end():
    """A blade hanging down beside the stem, its lower end a centimetre
    nearer to the stem than its upper one: the branch point nearest to any
    of its points is at its bottom, 12 cm below the petiole; the estimate
    is at its upper end."""
    stem = _Stem()
    blade = _Blade(x_top=0.025, x_bottom=0.015, z_top=0.45)
    nearest_any = stem[cKDTree(stem).query(blade)[1][np.argmin(cKDTree(stem).query(blade)[0])]]
    assert nearest_any[2] < 0.35                 # what the nearest point gives
    hinge = EstimateHinge(blade, stem)
    assert abs(hinge[2] - 0.45) < 0.03


def test_a_leaf_held_out_from_its_stem_hinges_at_its_near_end():
    """A blade held out horizontally, its base 1 cm from the stem: the base
    end is the one nearer the branch (whatever the heights), and the
    estimate is the nearest branch point, as before."""
    stem = _Stem()
    s, v = np.meshgrid(np.arange(0, 0.12, 0.003), np.arange(-0.025, 0.025, 0.003))
    # tilted up 20 deg towards the tip: the tip is the upper end
    blade = np.c_[0.01 + s.ravel() * np.cos(0.35), v.ravel(), 0.4 + s.ravel() * np.sin(0.35)]
    d, j = cKDTree(stem).query(blade)
    hinge = EstimateHinge(blade, stem)
    assert np.allclose(hinge, stem[j[np.argmin(d)]])
    assert abs(hinge[2] - 0.4) < 0.01


def test_blade_ends_are_the_quarters_at_each_end_of_its_long_axis():
    blade = _Blade(0.02, 0.02, 0.5, length=0.12, width=0.03)
    a, b = BladeEnds(blade)
    assert not (a & b).any()
    zs = sorted([blade[a][:, 2].mean(), blade[b][:, 2].mean()])
    assert zs[0] < 0.5 - 0.09 and zs[1] > 0.5 - 0.03
    assert 0.2 < a.mean() < 0.3 and 0.2 < b.mean() < 0.3
    assert EstimateHinge(np.zeros((0, 3)), _Stem()) is None
    assert EstimateHinge(blade, np.zeros((0, 3))) is None
