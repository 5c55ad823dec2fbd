import numpy as np

from lmap_drake.shape.branch import CompleteBranch, CompleteBranches, EstimateCylinder


def _branch_points(rng, r=0.006, gap=(0.28, 0.36), tilt=0.15):
    cam = np.array([0.0, -0.5, 0.3])
    axis = np.array([tilt, 0.05, 1.0])
    axis /= np.linalg.norm(axis)
    u = np.cross(axis, [0, 1.0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    s = rng.uniform(0.2, 0.45, 8000)
    th = rng.uniform(0, 2 * np.pi, 8000)
    n = np.cos(th)[:, None] * u + np.sin(th)[:, None] * v
    p = s[:, None] * axis + r * n
    visible = np.einsum("ij,ij->i", n, cam - p) > 0
    hidden = (s > gap[0]) & (s < gap[1])
    keep = visible & ~hidden
    return cam, axis, p[keep] + rng.normal(0, 0.0003, (keep.sum(), 3))


def test_radius_and_axis_from_half_cylinder():
    rng = np.random.default_rng(0)
    cam, axis, pts = _branch_points(rng, r=0.008)
    centre, a, s0, s1, radius = EstimateCylinder(pts)
    assert abs(radius - 0.008) < 0.0015
    assert abs(abs(a @ axis) - 1) < 1e-3
    # The fitted axis passes near the true one (not the visible half's centroid).
    d = np.linalg.norm(np.cross(centre, axis))
    assert d < 0.002


def test_branch_completion_bridges_a_gap_hidden_by_a_leaf():
    rng = np.random.default_rng(1)
    cam, axis, pts = _branch_points(rng)
    s = pts @ axis
    assert not ((s > 0.29) & (s < 0.35)).any()
    b = CompleteBranch(pts, cam)
    ss = b.samples_W @ axis
    in_gap = b.samples_W[(ss > 0.29) & (ss < 0.35)]
    assert len(in_gap) > 100
    # Gap samples lie on the true cylinder surface and go all around it.
    radial = in_gap - (in_gap @ axis)[:, None] * axis
    assert np.all(np.abs(np.linalg.norm(radial, axis=1) - 0.006) < 0.002)
    ang = np.arctan2(radial @ np.cross(axis, [0, 1.0, 0]), radial[:, 1])
    assert np.ptp(ang) > 5.0
    # Observed points are close to the completed mesh samples.
    from scipy.spatial import cKDTree
    d, _ = cKDTree(b.samples_W).query(pts)
    assert np.percentile(d, 95) < 0.0025
    assert abs(abs(b.axis_W @ axis) - 1) < 1e-3


def test_instances_are_completed_and_merged():
    rng = np.random.default_rng(2)
    cam, axis, p1 = _branch_points(rng)
    p2 = p1 + [0.15, 0, 0]
    pts = np.vstack([p1, p2])
    inst = np.r_[np.zeros(len(p1), int), np.ones(len(p2), int)]
    b = CompleteBranches(pts, inst, cam)
    assert b.samples_W[:, 0].min() < 0.1 and b.samples_W[:, 0].max() > 0.15
    assert CompleteBranches(pts[:5], inst[:5], cam) is None


def test_stalk_labelled_branch_is_its_own_part():
    rng = np.random.default_rng(3)
    cam, axis, main = _branch_points(rng, gap=(0, 0))
    # A short horizontal-ish stalk leaving the branch at s = 0.3.
    base = 0.3 * axis
    d = np.array([1.0, 0, -0.5])
    d /= np.linalg.norm(d)
    s = rng.uniform(0.0, 0.04, 600)
    th = rng.uniform(0, 2 * np.pi, 600)
    u = np.cross(d, [0, 1.0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(d, u)
    stalk = base + s[:, None] * d + 0.004 * (np.cos(th)[:, None] * u + np.sin(th)[:, None] * v)
    b = CompleteBranches(np.vstack([main, stalk]), None, cam)
    from scipy.spatial import cKDTree
    tip = base + 0.04 * d
    dist, _ = cKDTree(b.samples_W).query(tip)
    assert dist < 0.008
    assert abs(abs(b.axis_W @ axis) - 1) < 0.01
