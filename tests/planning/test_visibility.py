import numpy as np

from lmap_drake.planning.visibility import CountNewlySeen, VisibilityModel


def _sphere(c, r, n=4000, seed=0):
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return c + r * v / np.linalg.norm(v, axis=1, keepdims=True)


def _plate(center, half=0.05, step=0.002):
    g = np.arange(-half, half + 1e-9, step)
    u, v = np.meshgrid(g, g)
    return np.c_[center[0] + u.ravel(), np.full(u.size, center[1]), center[2] + v.ravel()]


X_WC = np.array([[1, 0, 0, 0.5], [0, 0, 1, -0.6], [0, -1, 0, 0.3], [0, 0, 0, 1.0]])


def test_plate_moved_aside_reveals_the_fruit():
    fruit = _sphere(np.array([0.5, 0.0, 0.3]), 0.035)
    vis = VisibilityModel(X_WC, fruit, 0.003)
    n_max = vis.max_seen.sum()
    # roughly the front hemisphere is seen with the fruit alone
    assert 0.3 * len(vis.fruit_W) < n_max < 0.7 * len(vis.fruit_W)
    blocked = vis.Seen(_plate([0.5, -0.06, 0.3]))
    aside = vis.Seen(_plate([0.5 + 0.12, -0.06, 0.3]))
    assert blocked.sum() < 0.05 * n_max
    assert aside.sum() > 0.95 * n_max
    assert CountNewlySeen(aside, blocked) > 0.9 * n_max
    # an occluder behind the fruit hides nothing
    assert vis.Seen(_plate([0.5, 0.08, 0.3])).sum() == n_max
