"""De-projection, depth filtering, outliers, DBSCAN, voxels, semantic sets."""
import numpy as np
import pytest

from lmap_drake.labels import BRANCH, FRUIT, LEAF, DecodeLabels
from lmap_drake.perception.config import PerceptionConfig
from lmap_drake.perception.points import (BuildSemanticScene, DbscanLabels, DeprojectPixels,
                                          Intrinsics, StatisticalOutlierMask, ValidDepthMask,
                                          VoxelDownsample)
from perception_scenes import Render

K = Intrinsics(8, 6, 10.0, 10.0, 3.5, 2.5)

# Camera 0.3 m in front of the placeholder leaf, looking along +y_W (z_C = +y_W,
# y_C = -z_W): the leaf's front face is the plane y_W = -0.101.
# the renderer's exact images (this file tests de-projection, not the sensor model)
IDEAL = "{camera_noise: {enabled: false}}"
FACING_LEAF = ("cameras: {camera0: {name: camera0, width: 320, height: 240, "
               "focal: !FocalLength {x: 228.4, y: 228.5}, center_x: 161.3, center_y: 118.7, "
               "X_PB: {base_frame: world, translation: [0.5, -0.40, 0.355], "
               "rotation: !Rpy {deg: [-90.0, 0.0, 0.0]}}}}")


def test_deprojection_of_rendered_plane_within_2mm():
    from lmap_drake.scenario import LoadScenario
    from lmap_drake.plants.plant_station import MakePlantStation
    s = LoadScenario(scenario_text=[FACING_LEAF, IDEAL])
    station = MakePlantStation(s)
    ctx = station.CreateDefaultContext()
    depth = station.GetOutputPort("camera0.depth_image").Eval(ctx).data[..., 0]
    cls, _ = DecodeLabels(station.GetOutputPort("camera0.label_image").Eval(ctx).data)
    cam = s.cameras["camera0"]
    Kc = Intrinsics.FromCameraConfig(cam)
    assert (Kc.cx, Kc.cy, Kc.width) == (161.3, 118.7, 320)
    leaf = cls == LEAF
    assert leaf.sum() > 2000
    p = DeprojectPixels(depth, leaf, Kc, cam.X_PB.GetDeterministicValue())
    assert len(p) == leaf.sum()
    # on the plane y = -0.101 (depth error)
    assert np.abs(p[:, 1] + 0.101).max() < 2e-3
    # and inside the plate's extent (x 0.45..0.55, z 0.3225..0.3875): lateral error
    lo, hi = p.min(axis=0), p.max(axis=0)
    assert abs(lo[0] - 0.45) < 2e-3 and abs(hi[0] - 0.55) < 2e-3
    assert abs(lo[2] - 0.3225) < 2e-3 and abs(hi[2] - 0.3875) < 2e-3


def test_deprojection_matches_pinhole_and_pose():
    depth = np.full((6, 8), 2.0, np.float32)
    mask = np.zeros((6, 8), bool)
    mask[2, 5] = True
    p_C = DeprojectPixels(depth, mask, K)
    np.testing.assert_allclose(p_C, [[(5 - 3.5) * 0.2, (2 - 2.5) * 0.2, 2.0]])
    X = np.eye(4)
    X[:3, :3] = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]
    X[:3, 3] = [1, 2, 3]
    p_W = DeprojectPixels(depth, mask, K, X)
    np.testing.assert_allclose(p_W[0], X[:3, :3] @ p_C[0] + [1, 2, 3])


def test_nan_inf_zero_negative_and_far_depth_are_dropped():
    depth = np.full((6, 8), 1.0, np.float32)
    depth[0, 0], depth[0, 1], depth[0, 2] = np.nan, np.inf, -np.inf
    depth[0, 3], depth[0, 4], depth[0, 5] = 0.0, -1.0, 2.0
    valid = ValidDepthMask(depth, depth_cut=1.5)
    assert valid.sum() == 48 - 6
    p = DeprojectPixels(depth, np.ones_like(valid), K)
    assert len(p) == 48 - 5 and np.all(np.isfinite(p))  # no cut: only 2.0 m survives


def test_all_nan_depth_gives_empty_scene_with_flags():
    cm = np.full((6, 8), FRUIT)
    scene = BuildSemanticScene(cm, np.full((6, 8), np.nan), K, np.eye(4), PerceptionConfig())
    assert scene.is_empty()
    assert {"no_valid_depth", "no_fruit_in_view", "empty_scene"} <= set(scene.flags)
    assert scene.fruit_points_W.shape == (0, 3) and scene.fruit_instance.shape == (0,)


def test_empty_masks_give_empty_sets_not_a_crash():
    scene = BuildSemanticScene(np.zeros((6, 8), int), np.ones((6, 8)), K, np.eye(4),
                               PerceptionConfig())
    assert scene.is_empty() and "empty_scene" in scene.flags
    assert "no_valid_depth" not in scene.flags


def test_outlier_removal_drops_far_point():
    rng = np.random.default_rng(0)
    pts = np.concatenate([rng.normal(0, 0.005, (300, 3)), [[0.3, 0.3, 0.3]]])
    keep = StatisticalOutlierMask(pts, 20, 2.0)
    assert not keep[-1] and keep[:-1].mean() > 0.9
    assert StatisticalOutlierMask(pts[:5], 20, 2.0).all()  # too few: unchanged


def test_dbscan_splits_two_blobs_largest_first():
    rng = np.random.default_rng(1)
    a = rng.uniform(-0.01, 0.01, (400, 3))
    b = rng.uniform(-0.01, 0.01, (200, 3)) + [0.1, 0, 0]
    labels = DbscanLabels(np.concatenate([b, a, [[1.0, 1.0, 1.0]]]), 0.008, 30)
    assert set(labels[:200]) == {1} and set(labels[200:600]) == {0} and labels[-1] == -1
    assert DbscanLabels(np.zeros((0, 3)), 0.008, 30).shape == (0,)


def test_voxel_downsample_keeps_instances_apart():
    pts = np.array([[0.0001, 0, 0], [0.0002, 0, 0], [0.0001, 0, 0], [0.01, 0, 0]])
    out, inst = VoxelDownsample(pts, 0.003, np.array([0, 0, 1, 0]))
    assert len(out) == 3
    assert sorted(inst.tolist()) == [0, 0, 1]
    out2, _ = VoxelDownsample(pts, 0.0)
    assert len(out2) == 4


def test_semantic_scene_from_rendered_labels():
    v = Render()
    cls, _ = DecodeLabels(v.label)
    scene = BuildSemanticScene(cls, v.depth, v.K, v.X_WC, PerceptionConfig())
    s = v.scenario.plant_scene
    assert not scene.flags
    for name in ("branch", "leaf", "fruit"):
        pts = getattr(scene, f"{name}_points_W")
        inst = getattr(scene, f"{name}_instance")
        assert len(pts) > 20 and len(inst) == len(pts)
    # Fruit points lie on the fruit: within its half-size of the centre.
    c = np.asarray(getattr(s, "fruit_center_W", scene.fruit_points_W.mean(axis=0)))
    d = np.linalg.norm(scene.fruit_points_W - c, axis=1)
    assert d.max() < 0.06
    # Voxel size respected: no two fruit points of one instance closer than ~voxel/2.
    from scipy.spatial import cKDTree
    dd, _ = cKDTree(scene.leaf_points_W).query(scene.leaf_points_W, k=2)
    assert np.median(dd[:, 1]) > 0.0015
    # Branch points lie near the vertical branch axis.
    if hasattr(s, "p_W_branch_base"):
        r = np.linalg.norm(scene.branch_points_W[:, :2] - np.asarray(s.p_W_branch_base)[:2], axis=1)
        assert r.max() < 0.015


def test_background_ray_ends_measured_far_and_no_data():
    from lmap_drake.labels import BACKGROUND
    from lmap_drake.perception.points import BackgroundRayEnds
    depth = np.full((6, 8), 1.0)
    depth[0, 0], depth[0, 2], depth[2, 0] = np.inf, np.nan, 0.0
    cm = np.full((6, 8), BACKGROUND)
    cm[4, 4] = FRUIT
    bg = cm == BACKGROUND
    ends = BackgroundRayEnds(bg, depth, K, np.eye(4), stride=2, no_return_range=2.0)
    # stride 2: 3 x 4 pixels; (4, 4) is fruit, (0, 2) NaN and (2, 0) 0 are no data
    assert len(ends) == 12 - 3
    far = np.linalg.norm(ends, axis=1) > 1.5
    assert far.sum() == 1   # the +inf pixel, at 2 m along its ray
    np.testing.assert_allclose(np.linalg.norm(ends[far]), 2.0)
    np.testing.assert_allclose(ends[far][0] / 2.0, np.array([-3.5, -2.5, 10.0]) /
                               np.linalg.norm([-3.5, -2.5, 10.0]))
    assert np.allclose(ends[~far][:, 2], 1.0)   # measured: de-projected depth
    # range 0: +inf pixels carve nothing
    assert len(BackgroundRayEnds(bg, depth, K, np.eye(4), 2, 0.0)) == 12 - 4
    with pytest.raises(ValueError, match="background_stride"):
        BackgroundRayEnds(bg, depth, K, np.eye(4), stride=0)


def test_no_return_pixels_next_to_returns_are_dropouts_not_free_space():
    """A sensor dropout (a glancing rim, a speckle) lies beside surfaces it
    sees; only no-return pixels farther than the margin from any return
    carve free space."""
    from lmap_drake.perception.points import BackgroundRayEnds
    depth = np.full((40, 40), np.inf)
    depth[10:30, 10:30] = 0.5          # a surface
    depth[20, 20] = np.inf             # a speckle inside it
    depth[10:30, 29] = np.inf          # a dropout column along its rim
    bg = ~np.isfinite(depth)
    ends = BackgroundRayEnds(bg, depth, K, np.eye(4), 1, 2.0, no_return_margin_px=4.0)
    u = np.rint(ends[:, 0] / ends[:, 2] * K.fx + K.cx).astype(int)
    v = np.rint(ends[:, 1] / ends[:, 2] * K.fy + K.cy).astype(int)
    carved = np.zeros(depth.shape, bool)
    carved[v, u] = True
    assert carved.sum() == len(ends) > 0
    assert not carved[20, 20] and not carved[10:30, 29:33].any()
    rows, cols = np.nonzero(np.isfinite(depth))
    for y, x in zip(v, u):
        assert np.hypot(rows - y, cols - x).min() > 4.0
    every = BackgroundRayEnds(bg, depth, K, np.eye(4), 1, 2.0, no_return_margin_px=0.0)
    assert len(every) == bg.sum()


def test_semantic_scene_carries_background_rays_in_world():
    from lmap_drake.labels import BACKGROUND
    cm = np.full((6, 8), BACKGROUND)
    cm[2:5, 2:6] = LEAF
    depth = np.full((6, 8), np.inf)
    depth[2:5, 2:6] = 0.5
    X = np.eye(4)
    X[:3, 3] = [1.0, 2.0, 3.0]
    p = PerceptionConfig(outlier_neighbors=3, dbscan_min_points=1, background_stride=1,
                    no_return_margin_px=0.0)
    scene = BuildSemanticScene(cm, depth, K, X, p)
    assert len(scene.background_points_W) == 48 - 12
    np.testing.assert_allclose(np.linalg.norm(scene.background_points_W - X[:3, 3], axis=1),
                               p.no_return_free_range)


def test_flying_pixels_between_two_surfaces_are_flagged_smooth_ones_are_not():
    from lmap_drake.perception.points import FlyingPixelMask
    depth = np.full((20, 30), 0.58)          # the fruit behind
    depth[:, :15] = 0.55                     # the leaf in front
    depth[:, 15] = 0.565                     # mixed pixels in the 3 cm gap
    rng = np.random.default_rng(0)
    depth += rng.normal(0, 0.0015, depth.shape)   # 1.5 mm sensor noise
    depth[5, 5] = np.inf
    flying = FlyingPixelMask(depth, 0.005)
    assert flying[:, 15].all()
    assert flying[:, :14].sum() + flying[:, 17:].sum() == 0
    tilted = 0.5 + 0.004 * np.arange(30)[None, :] * np.ones((20, 1))   # 4 mm per pixel
    assert not FlyingPixelMask(tilted, 0.005).any()
    assert not FlyingPixelMask(depth, 0.0).any()


def test_robot_self_filter_drops_points_on_the_robot_only():
    from lmap_drake.perception.points import RemovePointsNear
    from lmap_drake.planning.robot_model import RobotModel
    from lmap_drake.station.config import RobotConfig
    from lmap_drake.types import SemanticScene
    robot = RobotModel(RobotConfig().X_WB.GetDeterministicValue())
    q = np.array(RobotConfig().initial_q)
    rng = np.random.default_rng(0)
    on_robot = robot.SurfacePoints(q)[rng.choice(robot.num_points, 200, replace=False)]
    on_robot += rng.normal(scale=0.002, size=on_robot.shape)     # sensor noise
    plant = rng.uniform([0.45, -0.05, 0.25], [0.55, 0.05, 0.40], (300, 3))
    d_plant = np.min(np.linalg.norm(plant[:, None] - robot.SurfacePoints(q)[None], axis=2),
                     axis=1)
    assert d_plant.min() > 0.05                                  # the plant is clear of the arm
    scene = SemanticScene(leaf_points_W=np.vstack([plant, on_robot[:100]]),
                          leaf_instance=np.zeros(400, np.int64),
                          fruit_points_W=on_robot[100:], fruit_instance=np.ones(100, np.int64),
                          flags=["green_fruit_detected"])
    out, dropped = RemovePointsNear(scene, robot.SurfacePoints(q), 0.01)
    assert dropped == 200
    assert np.array_equal(out.leaf_points_W, plant) and len(out.leaf_instance) == 300
    assert len(out.fruit_points_W) == 0 and "no_fruit_in_view" in out.flags
    assert "robot_filtered" in out.flags and "green_fruit_detected" in out.flags
    assert len(scene.fruit_points_W) == 100                      # the input is not changed
    same, n = RemovePointsNear(scene, robot.SurfacePoints(q), 0.0)   # 0 = off
    assert n == 0 and same is scene


def _Patch(origin, u_axis, v_axis, size_u, size_v, spacing=0.003):
    u, v = np.meshgrid(np.arange(0, size_u, spacing), np.arange(0, size_v, spacing))
    return (np.asarray(origin, float) + u.reshape(-1, 1) * np.asarray(u_axis, float)
            + v.reshape(-1, 1) * np.asarray(v_axis, float))


def test_touching_leaves_are_split_where_their_blades_meet_at_an_angle():
    """A 6 x 5 cm blade whose edge rests on another blade at 50 degrees
    (one cluster) comes apart into two leaves, each with at least 85 % of
    its points (the points at the contact have blended normals)."""
    from lmap_drake.perception.points import SplitTouchingLeaves
    a = _Patch([0, 0, 0], [1, 0, 0], [0, 1, 0], 0.08, 0.05)
    t = np.deg2rad(50)
    b = _Patch([0.04, 0, 0.003], [np.cos(t), 0, np.sin(t)], [0, 1, 0], 0.06, 0.05)
    pts = np.vstack([a, b])
    truth = np.r_[np.zeros(len(a), int), np.ones(len(b), int)]
    ids = SplitTouchingLeaves(pts, np.zeros(len(pts), np.int64), p_WC=[0.0, -0.1, 0.5])
    assert len(np.unique(ids)) == 2
    major = []
    for k in (0, 1):
        vals, counts = np.unique(ids[truth == k], return_counts=True)
        assert counts.max() >= 0.85 * (truth == k).sum()
        major.append(vals[np.argmax(counts)])
    assert major[0] != major[1]
    # noise stays noise, other instances keep their ids
    ids2 = SplitTouchingLeaves(pts, np.r_[np.full(len(a), 3), np.full(len(b), -1)], [0, -0.1, 0.5])
    assert set(np.unique(ids2)) == {-1, 3}


def test_one_curved_blade_is_not_split():
    """A blade bent on a 6 cm radius (more than a leaf bends) and a flat
    blade 2 cm away stay as they were."""
    from lmap_drake.perception.points import SplitTouchingLeaves
    th, y = np.meshgrid(np.linspace(0, 1.2, 25), np.arange(0, 0.05, 0.003))
    curved = np.c_[0.06 * np.sin(th.ravel()), y.ravel(), 0.06 * (1 - np.cos(th.ravel()))]
    flat = _Patch([0, 0.07, 0], [1, 0, 0], [0, 1, 0], 0.05, 0.04)
    pts = np.vstack([curved, flat])
    inst = np.r_[np.zeros(len(curved), int), np.ones(len(flat), int)]
    ids = SplitTouchingLeaves(pts, inst, p_WC=[0.0, 0.0, 0.5])
    assert np.array_equal(ids, inst)


def test_blades_lying_flush_are_split_by_size():
    """Two 6 x 5 cm blades side by side in one plane (no angle to split
    at) make an instance twice the size of the plant's other leaves: it is
    cut in two along their boundary; leaves of the common size, noise and a
    plant of too few leaves to know the size are left alone."""
    from lmap_drake.perception.points import SplitOversizedLeaves
    blade = lambda x, y: _Patch([x, y, 0.0], [1, 0, 0], [0, 1, 0], 0.06, 0.05)   # noqa: E731
    flush = np.vstack([blade(0.0, 0.0), blade(0.06, 0.0)])
    singles = [blade(0.0, 0.2), blade(0.1, 0.2), blade(0.2, 0.2)]
    pts = np.vstack([flush] + singles + [[[1.0, 1.0, 1.0]]])
    n = len(singles[0])
    inst = np.r_[np.zeros(len(flush), int), np.repeat([1, 2, 3], n), -1]
    ids = SplitOversizedLeaves(pts, inst)
    left = pts[:, 0] < 0.06 - 1e-9
    mine = np.arange(len(pts)) < len(flush)
    a, b = np.unique(ids[mine & left]), np.unique(ids[mine & ~left])
    assert len(a) == 1 and len(b) == 1 and a[0] != b[0]
    assert 0 in (a[0], b[0]) and max(a[0], b[0]) == 4          # a new id for the other
    assert np.array_equal(ids[~mine], inst[~mine])
    # two instances are too few to know a leaf's size
    few = np.r_[np.zeros(len(flush), int), np.ones(n, int)]
    assert np.array_equal(SplitOversizedLeaves(np.vstack([flush, singles[0]]), few), few)


def test_three_flush_blades_among_four_instances_are_split_in_three():
    """Three blades lying flush as one instance beside three single
    leaves: the merged instance is itself the upper quartile of the four,
    so the spread is judged on the instances that may be single leaves
    (all of a size here) and it is cut in three, one blade each."""
    from lmap_drake.perception.points import SplitOversizedLeaves
    blade = lambda x, y: _Patch([x, y, 0.0], [1, 0, 0], [0, 1, 0], 0.06, 0.05)   # noqa: E731
    flush = [blade(0.0, 0.0), blade(0.06, 0.0), blade(0.12, 0.0)]
    singles = [blade(0.0, 0.2), blade(0.1, 0.2), blade(0.2, 0.2)]
    pts = np.vstack(flush + singles)
    n = len(singles[0])
    inst = np.r_[np.zeros(3 * n, int), np.repeat([1, 2, 3], n)]
    ids = SplitOversizedLeaves(pts, inst)
    parts = [np.unique(ids[k * n:(k + 1) * n], return_counts=True) for k in range(3)]
    majors = [v[np.argmax(c)] for v, c in parts]
    assert len(set(majors)) == 3
    assert all(c.max() >= 0.8 * n for _, c in parts)
    assert np.array_equal(ids[3 * n:], inst[3 * n:])


def test_whole_leaves_among_many_pieces_are_not_cut():
    """A dense view: 20 pieces of partly seen leaves (1.5 x 1.2 cm, all
    of a size) and 8 whole leaves of 3 to 4.5 times their size. The pieces
    look uniform among themselves, but with this many instances the size
    premise is judged on all of them, which spread too much to say what a
    leaf's size is: nothing is cut (``gh_lanceolate_leaves``: 1 of 21
    leaves matched when it was judged on the pieces)."""
    from lmap_drake.perception.points import FEW_INSTANCES, SplitOversizedLeaves
    piece = lambda x: _Patch([x, 0.5, 0.0], [1, 0, 0], [0, 1, 0], 0.015, 0.012)   # noqa: E731
    leaf = lambda x, w: _Patch([x, 0.0, 0.0], [1, 0, 0], [0, 1, 0], w, 0.02)       # noqa: E731
    parts = [piece(0.05 * k) for k in range(20)]
    parts += [leaf(0.1 * k, 0.03 + 0.005 * (k % 4)) for k in range(8)]
    assert len(parts) >= FEW_INSTANCES
    pts = np.vstack(parts)
    inst = np.concatenate([np.full(len(p), k) for k, p in enumerate(parts)])
    assert np.array_equal(SplitOversizedLeaves(pts, inst), inst)


def test_fruit_instances_carry_the_mean_confidence_of_their_pixels():
    v = Render()
    cls, inst = DecodeLabels(v.label)
    params = PerceptionConfig()
    bare = BuildSemanticScene(cls, v.depth, v.K, v.X_WC, params)
    assert bare.fruit_confidence == {}                       # no confidences given
    fruit = (cls == FRUIT) & (inst >= 0)
    ids = sorted(set(inst[fruit].tolist()))
    conf = {(FRUIT, i): 0.37 for i in ids}
    conf[(LEAF, 0)] = 0.99                                   # not a fruit's: not carried
    one = BuildSemanticScene(cls, v.depth, v.K, v.X_WC, params, instance_map=inst,
                             confidence=conf)
    got = set(one.fruit_instance[one.fruit_instance >= 0].tolist())
    assert got and set(one.fruit_confidence) == got
    assert all(c == 0.37 for c in one.fruit_confidence.values())
    # the fruit's pixels split (a checkerboard) into two image instances of
    # 0.2 and 0.8: each point cloud instance (a DBSCAN cluster across both)
    # gets their pixel-weighted mean
    split = inst.copy()
    r, c = np.indices(inst.shape)
    split[fruit & ((r + c) % 2 == 0)] = 50
    two = BuildSemanticScene(cls, v.depth, v.K, v.X_WC, params, instance_map=split,
                             confidence={(FRUIT, 50): 0.2,
                                         **{(FRUIT, i): 0.8 for i in ids if i != 50}})
    assert set(two.fruit_confidence) == got
    assert all(0.4 < c < 0.6 for c in two.fruit_confidence.values())
    assert len(two.fruit_points_W) == len(one.fruit_points_W)   # points unchanged


def test_neighbour_reads_the_shifted_pixel_and_fills_past_the_edge():
    from lmap_drake.perception.points import Neighbour
    a = np.arange(12.0).reshape(3, 4)
    right = Neighbour(a, 0, 1, np.nan)
    assert np.array_equal(right[:, :3], a[:, 1:]) and np.isnan(right[:, 3]).all()
    up = Neighbour(a.astype(int), -1, 0, -1)
    assert np.array_equal(up[1:], a[:2].astype(int)) and (up[0] == -1).all()
    assert Neighbour(a > 5, 1, -1, False).dtype == bool
