"""View fusion: leaf from the newest view, fruit and branch accumulate."""
import numpy as np

from lmap_drake.labels import DecodeLabels
from lmap_drake.perception.fusion import FuseViews
from lmap_drake.perception.config import PerceptionConfig
from lmap_drake.perception.points import BuildSemanticScene
from lmap_drake.types import SemanticScene
from perception_scenes import Render


def _scene(branch, leaf, fruit, fruit_inst=None):
    fi = np.zeros(len(fruit), np.int64) if fruit_inst is None else np.asarray(fruit_inst)
    return SemanticScene(branch_points_W=np.asarray(branch, float).reshape(-1, 3),
                         leaf_points_W=np.asarray(leaf, float).reshape(-1, 3),
                         fruit_points_W=np.asarray(fruit, float).reshape(-1, 3),
                         branch_instance=np.zeros(len(branch), np.int64),
                         leaf_instance=np.zeros(len(leaf), np.int64), fruit_instance=fi)


def test_leaf_from_newest_fruit_and_branch_accumulate():
    old = _scene([[0, 0, 0]], [[0, 0.1, 0]], [[0.2, 0, 0]])
    new = _scene([[0, 0, 0.05]], [[0, 0.3, 0]], [[0.2, 0.0, 0.001], [0.2, 0.05, 0]])
    new.X_WC = np.diag([1.0, 1.0, 1.0, 1.0]) * 2
    f = FuseViews(old, new, voxel_size=0.003)
    np.testing.assert_allclose(f.leaf_points_W, [[0, 0.3, 0]])
    assert len(f.branch_points_W) == 2
    assert len(f.fruit_points_W) == 2  # two coincident points merge into one voxel
    assert f.num_views == 2 and "fused_views" in f.flags
    np.testing.assert_allclose(f.X_WC, new.X_WC)


def test_new_instances_join_overlapping_old_ones():
    rng = np.random.default_rng(0)
    a = rng.uniform(0, 0.02, (100, 3))
    b = a + [0.2, 0, 0]
    old = _scene([], [], np.concatenate([a, b]), [0] * 100 + [1] * 100)
    new = _scene([], [], np.concatenate([b + 0.001, a + [0, 0, 0.5]]), [0] * 100 + [1] * 100)
    f = FuseViews(old, new, voxel_size=0.0)
    near_b = f.fruit_points_W[:, 0] > 0.1
    assert set(f.fruit_instance[near_b]) == {1}
    assert set(f.fruit_instance[f.fruit_points_W[:, 2] > 0.4]) == {2}


def test_fusing_with_empty_views():
    full = _scene([[0, 0, 0]], [[1, 0, 0]], [[2, 0, 0]])
    empty = SemanticScene(flags=["empty_scene"])
    f = FuseViews(full, empty)
    assert len(f.fruit_points_W) == 1 and len(f.leaf_points_W) == 0
    assert "no_leaf_in_view" in f.flags
    assert FuseViews(None, full) is full
    assert FuseViews(empty, empty).is_empty()


def test_fusing_two_rendered_views_grows_the_fruit():
    """Two camera poses of the same plant: the fused fruit set covers more
    of the fruit than either view, and its points still lie on the fruit."""
    params = PerceptionConfig()
    scenes = []
    for yaw in (-25.0, 25.0):
        x = 0.5 + np.sin(np.deg2rad(yaw)) * 0.55
        cam = ("cameras: {camera0: {name: camera0, width: 320, height: 240, "
               "focal: !FocalLength {x: 228.4, y: 228.5}, center_x: 160.0, center_y: 120.0, "
               f"X_PB: {{base_frame: world, translation: [{x:.3f}, -0.55, 0.45], "
               f"rotation: !Rpy {{deg: [-105.0, 0.0, {yaw}]}}}}}}}}")
        v = Render(camera=cam)
        cls, _ = DecodeLabels(v.label)
        scenes.append(BuildSemanticScene(cls, v.depth, v.K, v.X_WC, params))
    fused = FuseViews(scenes[0], scenes[1], params.voxel_size)
    n0, n1 = len(scenes[0].fruit_points_W), len(scenes[1].fruit_points_W)
    assert len(fused.fruit_points_W) > max(n0, n1) + 20
    # the leaf splits the fruit into fragments in each view; fusion joins a
    # new view's fragment to the old one it overlaps instead of adding it
    count = [len(set(s.fruit_instance.tolist()) - {-1}) for s in (*scenes, fused)]
    assert min(count[:2]) >= 1 and 1 <= count[2] < count[0] + count[1], count
    np.testing.assert_allclose(fused.leaf_points_W, scenes[1].leaf_points_W)


def test_background_rays_unite_only_for_an_unmoved_camera():
    old = _scene([[0, 0, 0]], [[0, 0.1, 0]], [[0.2, 0, 0]])
    new = _scene([[0, 0, 0]], [[0, 0.2, 0]], [[0.2, 0, 0]])
    old.background_points_W = np.array([[0, 0, 2.0], [0.1, 0, 2.0]])
    new.background_points_W = np.array([[0, 0, 2.0], [0, 0.1, 2.0]])
    f = FuseViews(old, new)
    assert len(f.background_points_W) == 3        # the shared ray once
    moved = _scene([[0, 0, 0]], [[0, 0.2, 0]], [[0.2, 0, 0]])
    moved.background_points_W = new.background_points_W
    moved.X_WC = np.eye(4)
    moved.X_WC[0, 3] = 0.05
    np.testing.assert_allclose(FuseViews(old, moved).background_points_W,
                               new.background_points_W)


def test_fused_fruit_instances_keep_the_higher_confidence():
    rng = np.random.default_rng(0)
    a = rng.uniform(0, 0.02, (100, 3))
    b = a + [0.2, 0, 0]
    old = _scene([], [], np.concatenate([a, b]), [0] * 100 + [1] * 100)
    old.fruit_confidence = {0: 0.9, 1: 0.3}
    # the new view: b again (its id 0 here) more surely, and a new instance
    new = _scene([], [], np.concatenate([b + 0.001, a + [0, 0, 0.5]]), [0] * 100 + [1] * 100)
    new.fruit_confidence = {0: 0.6, 1: 0.4}
    f = FuseViews(old, new, voxel_size=0.0)
    assert f.fruit_confidence == {0: 0.9, 1: 0.6, 2: 0.4}
