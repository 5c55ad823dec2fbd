import numpy as np
import trimesh

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


def _ReferenceSeen(vis: VisibilityModel, occ: np.ndarray) -> np.ndarray:
    """Every occluder voxel splatted explicitly over its (2r+1)^2 pixels (the
    definition ``ZBuffer``'s min-filter implements)."""
    from lmap_drake.planning.visibility import NEAR, VoxelCenters
    h, w = vis.shape
    zbuf = np.full(h * w, np.inf)
    p_C = vis._to_camera(VoxelCenters(occ, vis.voxel))
    p_C = p_C[p_C[:, 2] > NEAR]
    uv = vis._project(p_C)
    rad = np.minimum(np.ceil(0.5 * vis.f * vis.voxel * np.sqrt(2) / p_C[:, 2]).astype(int), 64)
    for k in range(len(p_C)):
        r = rad[k]
        for du in range(-r, r + 1):
            for dv in range(-r, r + 1):
                pix = vis._pixels((uv[k] + [du, dv])[None])[0]
                if pix >= 0:
                    zbuf[pix] = min(zbuf[pix], p_C[k, 2])
    ok = vis._fruit_pix >= 0
    seen = np.zeros(len(vis.fruit_W), bool)
    pix, z, tol = vis._fruit_pix[ok], vis._fruit_z[ok], 0.75 * vis.voxel
    seen[ok] = (z <= vis._fruit_zbuf[pix] + tol) & (z < zbuf[pix] - tol)
    return seen


def test_zbuffer_matches_explicit_splatting_and_composes():
    rng = np.random.default_rng(5)
    fruit = _sphere(np.array([0.5, 0.0, 0.3]), 0.035)
    vis = VisibilityModel(X_WC, fruit, 0.003)
    for near_lens in (False, True):
        # scattered occluders in front of the fruit (some beyond the window's
        # edge); near the lens their footprints span many pixels
        y = (-0.55, -0.45) if near_lens else (-0.2, -0.04)
        occ = np.c_[rng.uniform(0.40, 0.60, 400), rng.uniform(*y, 400),
                    rng.uniform(0.20, 0.40, 400)]
        seen = vis.Seen(occ)
        assert 0 < seen.sum() < vis.max_seen.sum()
        assert np.array_equal(seen, _ReferenceSeen(vis, occ))
        # a buffer of part of the occluders, combined with the rest: the same
        base = vis.ZBuffer(occ[:150])
        assert np.array_equal(vis.Seen(occ[150:], base), seen)


def test_observed_marks_the_voxels_on_pixels_of_earlier_views():
    """``Observed``: the fruit voxels the camera sees whose pixel an
    observed point covers; none for no points; only the left half for
    points on the left half."""
    from lmap_drake.planning.visibility import VisibilityModel
    X_WC = np.array([[1, 0, 0, 0.5], [0, 0, 1, -0.6], [0, -1, 0, 0.3], [0, 0, 0, 1.0]])
    sphere = trimesh.creation.icosphere(4, 0.035).apply_translation([0.5, 0.0, 0.3])
    vis = VisibilityModel(X_WC, np.asarray(sphere.vertices), 0.003)
    assert not vis.Observed(np.zeros((0, 3))).any()
    front = np.asarray(sphere.vertices)[np.asarray(sphere.vertices)[:, 1] < 0]
    np.testing.assert_array_equal(vis.Observed(front), vis.max_seen)
    left = vis.Observed(front[front[:, 0] < 0.49])
    assert 0.3 * vis.max_seen.sum() < left.sum() < 0.6 * vis.max_seen.sum()
    assert not left[vis.fruit_W[:, 0] > 0.5].any()
