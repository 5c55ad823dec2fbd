import numpy as np

from lmap_drake.shape.free_space import (CarveFreeSpace, CarveFreeSpaceDDA, CarveFreeSpaceSamples,
                                         FreeSpacePoints,
                                         RegionAroundFruit, VoxelGrid)


def _scene(rng):
    """Camera at the origin looking +y at a sphere (fruit) in front of a wall."""
    cam = np.zeros(3)
    c = np.array([0.01, 0.4, 0.005])
    dirs = rng.normal(size=(4000, 3)) * [0.08, 0, 0.08] + [0, 1, 0]
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    pts = []
    for d in dirs:
        b = d @ c
        disc = b * b - (c @ c - 0.03 ** 2)
        t = b - np.sqrt(disc) if disc > 0 else 0.45 / d[1]
        pts.append(t * d)
    return cam, c, np.array(pts)


def test_vectorised_matches_dda_reference():
    rng = np.random.default_rng(0)
    cam, c, pts = _scene(rng)
    grid = VoxelGrid(origin=c - 0.045, voxel=0.003, shape=(30, 30, 30))
    sub = pts[rng.choice(len(pts), 600, replace=False)]
    fast = CarveFreeSpace(cam, sub, grid)
    ref = CarveFreeSpaceDDA(cam, sub, grid)
    assert len(ref) > 200
    inter = np.intersect1d(fast, ref).size
    union = np.union1d(fast, ref).size
    assert inter / union > 0.95
    # Samples on a segment always lie in voxels the exact traversal visits.
    assert np.setdiff1d(fast, ref).size <= 0.01 * len(fast)


def test_free_space_is_in_front_of_surfaces_only():
    rng = np.random.default_rng(1)
    cam, c, pts = _scene(rng)
    fruit = pts[np.linalg.norm(pts - c, axis=1) < 0.031]
    free = FreeSpacePoints(cam, pts, fruit, 0.003)
    assert len(free) > 500
    # Nothing inside the sphere (minus half a voxel diagonal) is free...
    assert np.all(np.linalg.norm(free - c, axis=1) > 0.03 - 0.003)
    # ... and nothing behind the wall or behind the sphere (its shadow).
    assert np.all(free[:, 1] < 0.45)
    d = free / np.linalg.norm(free, axis=1, keepdims=True)
    shadow = (np.linalg.norm(np.cross(d, c), axis=1) < 0.02) & (free @ c / np.linalg.norm(c) > 0.4)
    assert not shadow.any()
    # Voxels between the camera and the sphere's front are free.
    grid = RegionAroundFruit(fruit, 0.003)
    front = c - np.array([0, 0.04, 0])
    idx = grid.flat(grid.index(front[None]))[0]
    assert idx in CarveFreeSpace(cam, pts, grid)


def test_free_points_are_traversed_samples_not_voxel_centres():
    """Every free point lies on a carved ray segment, so none is inside the
    sphere (voxel centres of corner-clipped voxels can be), and there is one
    point per free voxel, inside that voxel."""
    rng = np.random.default_rng(2)
    cam, c, pts = _scene(rng)
    fruit = pts[np.linalg.norm(pts - c, axis=1) < 0.031]
    grid = RegionAroundFruit(fruit, 0.003)
    idx, means = CarveFreeSpaceSamples(cam, pts, grid)
    np.testing.assert_array_equal(idx, CarveFreeSpace(cam, pts, grid))
    np.testing.assert_array_equal(grid.flat(grid.index(means)), idx)
    centres = grid.centers(grid.unflat(idx))
    r_c = np.linalg.norm(centres - c, axis=1)
    r_m = np.linalg.norm(means - c, axis=1)
    assert (r_c < 0.03).sum() > 0          # the quantisation the means avoid
    assert r_m.min() > 0.03                 # rays stop one voxel before the sphere
    free = FreeSpacePoints(cam, pts, fruit, 0.003)   # (rays deduplicated per half voxel)
    assert len(free) > 0.95 * len(idx) and np.linalg.norm(free - c, axis=1).min() > 0.03


def test_background_rays_carve_beside_the_fruit():
    """Rays that miss everything (ends at 2 m, as perception's background
    ray ends) carve the space around the fruit's silhouette that rays to
    observed points never cross; they carve nothing inside the sphere."""
    rng = np.random.default_rng(3)
    cam, c, pts = _scene(rng)
    fruit = pts[np.linalg.norm(pts - c, axis=1) < 0.031]
    d = pts / np.linalg.norm(pts, axis=1, keepdims=True)
    bg_ends = 2.0 * d[np.linalg.norm(pts - c, axis=1) >= 0.031]   # the wall removed
    only_fruit = FreeSpacePoints(cam, fruit, fruit, 0.003)
    with_bg = FreeSpacePoints(cam, np.vstack([fruit, bg_ends]), fruit, 0.003)
    beside = lambda f: int(((f[:, 1] > c[1]) & (np.linalg.norm(f - c, axis=1) < 0.045)).sum())
    assert beside(only_fruit) == 0            # nothing passes beside the fruit's back half
    assert beside(with_bg) > 100
    assert np.linalg.norm(with_bg - c, axis=1).min() > 0.03 - 1e-9
