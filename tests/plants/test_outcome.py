"""Ground-truth measures of an episode (``lmap_drake.plants.outcome``)."""
import types

import numpy as np

from lmap_drake.labels import BRANCH, FRUIT, EncodeLabel
from lmap_drake.plants.outcome import TruthFruitOfInstance, TruthFruitOfPoints
from lmap_drake.types import SemanticScene


def test_a_target_is_matched_to_the_fruit_its_points_land_on_or_is_a_phantom():
    """Points projected into the render labels of their view: those on fruit
    1's pixels are fruit 1 (whatever fruit is nearer in space), those on a
    stalk are a phantom with the fraction on fruit."""
    K = types.SimpleNamespace(fx=100.0, fy=100.0, cx=50.0, cy=50.0)
    X_WC = np.eye(4)                      # camera at the origin looking along +z
    label = np.zeros((100, 100), np.int32)
    label[:, :40] = EncodeLabel(FRUIT, 0)
    label[:, 40:60] = EncodeLabel(BRANCH, 1)
    label[:, 60:] = EncodeLabel(FRUIT, 1)

    def at(u, v, z=0.5, n=20):           # n points seen at pixel columns u
        uu = np.linspace(u[0], u[1], n)
        return np.c_[(uu - 50.0) * z / 100.0, np.full(n, (v - 50.0) * z / 100.0), np.full(n, z)]

    assert TruthFruitOfPoints(at((65, 90), 50), label, K, X_WC) == (1, 1.0)
    assert TruthFruitOfPoints(at((5, 30), 20), label, K, X_WC) == (0, 1.0)
    fruit, fraction = TruthFruitOfPoints(np.vstack([at((42, 58), 50, n=30), at((62, 65), 50, n=10)]),
                                         label, K, X_WC)
    assert fruit is None and 0.2 < fraction < 0.3
    # behind the camera or outside the image: nothing to match
    assert TruthFruitOfPoints(at((65, 90), 50, z=-0.5), label, K, X_WC) == (None, 0.0)
    # a whole plant's scene: only the target instance's points count
    plant = SemanticScene(fruit_points_W=np.vstack([at((65, 90), 50, n=40), at((5, 30), 20)]),
                          fruit_instance=np.r_[np.zeros(40, int), np.ones(20, int)], X_WC=X_WC)
    assert TruthFruitOfInstance(plant, 1, label, K) == (0, 1.0)
    assert TruthFruitOfInstance(plant, 0, label, K) == (1, 1.0)
    assert TruthFruitOfInstance(plant, 7, label, K) is None


def test_a_moved_leaf_instance_is_matched_to_the_true_leaf_it_lands_on():
    """The same projection for leaves: points on leaf 7's pixels are leaf 7;
    points mostly on a fruit are no leaf."""
    from lmap_drake.labels import LEAF
    from lmap_drake.plants.outcome import TruthInstanceOfPoints
    K = types.SimpleNamespace(fx=100.0, fy=100.0, cx=50.0, cy=50.0)
    label = np.zeros((100, 100), np.int32)
    label[:, :50] = EncodeLabel(LEAF, 7)
    label[:, 50:] = EncodeLabel(FRUIT, 0)
    uu = np.linspace(5, 45, 20)
    left = np.c_[(uu - 50.0) * 0.5 / 100.0, np.zeros(20), np.full(20, 0.5)]
    assert TruthInstanceOfPoints(left, label, K, np.eye(4), LEAF) == (7, 1.0)
    right = left + [0.25, 0, 0]
    assert TruthInstanceOfPoints(right, label, K, np.eye(4), LEAF)[0] is None
