"""Several fruits and leaves: occluding leaves per fruit, the target scene
the single-fruit planner sees, the order of fruits, the leaf to move."""
import numpy as np
import trimesh

from lmap_drake.deformation.action import Action
from lmap_drake.planning.context import PlanningContext
from lmap_drake.planning.result import Candidate, PlanResult
from lmap_drake.planning.targets import (ChooseLeafPlan, OccludingLeaves, OrderTargets,
                                         TargetScene)
from lmap_drake.types import FruitEstimate, PlantEstimate, SemanticScene

# camera at y = -0.6 looking along +y (as in test_visibility)
X_WC = np.array([[1, 0, 0, 0.5], [0, 0, 1, -0.6], [0, -1, 0, 0.3], [0, 0, 0, 1.0]])


def _fruit(c, r=0.035):
    m = trimesh.creation.icosphere(3, r).apply_translation(c)
    c = np.asarray(c, float)
    return FruitEstimate(np.asarray(m.vertices), np.asarray(m.faces), np.eye(4), np.zeros(1),
                         c, np.array([0, 0, 1.0]),
                         sdf_W=lambda p: np.linalg.norm(p - c, axis=1) - r)


def _plate(cx, cz, half_x, half_z, y=-0.06, step=0.003):
    u, v = np.meshgrid(np.arange(-half_x, half_x + 1e-9, step),
                       np.arange(-half_z, half_z + 1e-9, step))
    return np.c_[cx + u.ravel(), np.full(u.size, y), cz + v.ravel()]


def _plant():
    A, B = _fruit([0.45, 0.0, 0.30]), _fruit([0.60, 0.0, 0.30])
    # leaves 0 and 1 each hide a half of A (left / right), leaf 2 most of B
    leaves = [_plate(0.43, 0.30, 0.022, 0.045), _plate(0.47, 0.30, 0.022, 0.045, y=-0.07),
              _plate(0.60, 0.31, 0.035, 0.03)]
    fruit_pts = np.vstack([A.vertices_W[A.vertices_W[:, 1] < -0.02],
                           B.vertices_W[B.vertices_W[:, 1] < -0.02]])
    fruit_id = np.r_[np.full((A.vertices_W[:, 1] < -0.02).sum(), 4),
                     np.full((B.vertices_W[:, 1] < -0.02).sum(), 7)]
    sem = SemanticScene(leaf_points_W=np.vstack(leaves),
                        leaf_instance=np.concatenate([np.full(len(p), j)
                                                      for j, p in enumerate(leaves)]),
                        fruit_points_W=fruit_pts, fruit_instance=fruit_id, X_WC=X_WC)
    return PlantEstimate(semantic=sem, fruits=[A, B], fruit_ids=[4, 7]), leaves


def test_occluding_leaves_per_fruit():
    plant, _ = _plant()
    a = OccludingLeaves(plant.fruits[0], plant, X_WC)
    assert a["visible"] < 0.5
    assert {d["leaf_id"] for d in a["leaves"]} == {0, 1}     # two leaves over A, not leaf 2
    assert all(d["gain"] > 0.1 for d in a["leaves"])
    b = OccludingLeaves(plant.fruits[1], plant, X_WC)
    assert [d["leaf_id"] for d in b["leaves"]] == [2]
    # without the leaves in front it, B is mostly seen: it loses nothing to A
    assert b["visible"] + b["leaves"][0]["gain"] > 0.9


def test_target_scene_keeps_the_rest_as_obstacles():
    plant, leaves = _plant()
    t = TargetScene(plant, 0, leaf_id=1)
    assert np.array_equal(t.semantic.leaf_points_W, leaves[1])
    assert len(t.other_leaves_W) == len(leaves[0]) + len(leaves[2])
    assert t.fruit is plant.fruits[0] and t.other_fruits == [plant.fruits[1]]
    assert set(np.unique(t.semantic.fruit_instance)) == {4}
    ctx = PlanningContext(t, X_WC, robot=None, q_current=np.zeros(6))
    # the robot and the moved leaf keep clear of both fruits
    d = ctx.fruit_sdf(np.array([[0.45, 0, 0.30], [0.60, 0, 0.30], [0.52, 0, 0.5]]))
    assert d[0] < 0 and d[1] < 0 and d[2] > 0.1
    assert ctx.fruit_box[0][0] < 0.42 and ctx.fruit_box[1][0] > 0.63
    # the other leaves and the other fruit occlude the target
    assert len(ctx.occluders_W) == len(t.other_leaves_W) + len(plant.fruits[1].vertices_W)


def test_a_target_s_leaves_share_the_fruits_obstacle_and_surfaces_unchanged():
    from lmap_drake.planning.context import SurfacesOf, TargetShared, VisibilitySurfaces
    plant, _ = _plant()
    shared = TargetShared(TargetScene(plant, 0, 0), "union")
    assert shared["visibility_surfaces"] == {}               # filled when first needed
    q = np.random.default_rng(0).uniform([0.35, -0.1, 0.2], [0.7, 0.1, 0.4], (500, 3))
    for leaf in (0, 1):
        own = PlanningContext(TargetScene(plant, 0, leaf), X_WC, robot=None,
                              q_current=np.zeros(6))
        ctx = PlanningContext(TargetScene(plant, 0, leaf), X_WC, robot=None,
                              q_current=np.zeros(6), shared=shared)
        assert ctx.fruit_sdf is shared["fruit_obstacle"][0]
        np.testing.assert_array_equal(ctx.fruit_sdf(q), own.fruit_sdf(q))
        np.testing.assert_array_equal(ctx.fruit_box, own.fruit_box)
        np.testing.assert_array_equal(SurfacesOf(ctx, "expected"),
                                      VisibilitySurfaces(plant.fruits[0], "expected"))
        assert SurfacesOf(ctx, "expected") is shared["visibility_surfaces"]["expected"]
        assert SurfacesOf(ctx, "estimate") is not shared["visibility_surfaces"]["expected"]
    assert set(shared["visibility_surfaces"]) == {"expected", "estimate"}


def test_order_and_leaf_choice():
    assert OrderTargets([0.5, 0.1, 0.97, 0.1]) == [1, 3, 0]

    def plan(seen, energy, seen_max=100):
        c = Candidate(Action(np.zeros(3), np.eye(3), [0, 0, 0.02]), 0, seen=seen,
                      energy=energy, num_leaf_nodes=10)
        return PlanResult("ok", "lmap", chosen=c, seen_max=seen_max)
    none = PlanResult("no_feasible_action", "lmap", seen_max=100)
    # within 0.05 of the best visibility the lower energy wins
    j, p, why = ChooseLeafPlan([(0, plan(97, 5e-6)), (1, plan(95, 1e-6)), (2, none)])
    assert j == 1 and "leaf 1" in why and "leaf 0" in why
    j, _, _ = ChooseLeafPlan([(0, plan(97, 5e-6)), (1, plan(80, 1e-7))])
    assert j == 0
    assert ChooseLeafPlan([(2, none)])[0] is None


def test_plan_target_weighs_both_leaves_over_one_fruit():
    """Two leaves over fruit A on a branch; the planner runs once per leaf
    and the choice names both; fruit order puts the least visible first."""
    from lmap_drake.planning.robot_model import RobotModel
    from lmap_drake.planning.targets import FruitOrder, PlanTarget
    from lmap_drake.scenario import Scenario
    s = Scenario()
    s.planner.num_grasps = 6
    s.planner.distances = [0.04, 0.08]
    s.planner.action_families = ["pull", "arc"]
    X = s.cameras["camera0"].X_PB.GetDeterministicValue().GetAsMatrix4()
    robot = RobotModel(s.robot.X_WB.GetDeterministicValue())
    # the synthetic plant of the planning-system tests, with a second fruit
    # beside it and the leaf split in two
    from tests.systems.test_planning_system import _scene
    one = _scene()
    leaf = one.semantic.leaf_points_W
    left = leaf[:, 0] < np.median(leaf[:, 0])
    c_B = one.fruit.center_W + [0.0, 0.0, -0.11]
    B = _fruit(c_B)
    fruit_pts = np.vstack([one.semantic.fruit_points_W, B.vertices_W[B.vertices_W[:, 1]
                                                                      < c_B[1] - 0.02]])
    ids = np.r_[np.zeros(len(one.semantic.fruit_points_W), int),
                np.ones(len(fruit_pts) - len(one.semantic.fruit_points_W), int)]
    sem = SemanticScene(branch_points_W=one.semantic.branch_points_W,
                        leaf_points_W=leaf, leaf_instance=np.where(left, 0, 1),
                        fruit_points_W=fruit_pts, fruit_instance=ids, X_WC=X)
    plant = PlantEstimate(semantic=sem, branch=one.branch, fruits=[one.fruit, B],
                          fruit_ids=[0, 1])
    order, occ = FruitOrder(plant, X, s.planner)
    vis = [o["visible"] for o in occ]
    assert order == [0] and vis[1] > 0.95 > vis[0]      # B is in the open
    t = PlanTarget(plant, 0, X, robot, np.asarray(s.robot.initial_q), s.planner, s.deformation)
    assert {j for j, _ in t.options} == {0, 1}
    assert t.plan is not None and t.plan.status == "ok", t.why
    assert t.leaf_id in (0, 1) and f"leaf {t.leaf_id}" in t.why
    assert t.plan is dict(t.options)[t.leaf_id]


def test_target_scene_without_a_leaf_to_move_keeps_every_leaf_as_an_obstacle():
    plant, leaves = _plant()
    t = TargetScene(plant, 1, leaf_id=None)
    assert len(t.semantic.leaf_points_W) == 0
    assert len(t.other_leaves_W) == sum(len(p) for p in leaves)
    assert t.fruit is plant.fruits[1] and t.other_fruits == [plant.fruits[0]]


def test_a_moved_leaf_segmented_with_its_neighbour_is_split_off():
    """Released, the moved leaf 0 lies back (3 mm off) beside leaf 1 and
    the segmenter made one instance of both: the points nearer leaf 0's
    points in the view its move was planned in than to the other leaves'
    there stay its instance, the rest become one of their own."""
    from lmap_drake.planning.targets import SeparateMovedLeaves
    _, leaves = _plant()
    before = leaves[0]
    now = [leaves[0] + [0.003, 0.0, 0.0], leaves[1], leaves[2]]
    sem = SemanticScene(leaf_points_W=np.vstack(now),
                        leaf_instance=np.r_[np.zeros(len(now[0]) + len(now[1]), int),
                                            np.ones(len(now[2]), int)], X_WC=X_WC)
    out, moved = SeparateMovedLeaves(sem, [before],
                                     other_leaf_points_W=[np.vstack(leaves[1:])])
    ids = np.asarray(out.leaf_instance)
    assert moved == [0] and "moved_leaf_separated" in out.flags
    was0 = np.r_[np.ones(len(now[0]), bool), np.zeros(len(now[1]) + len(now[2]), bool)]
    assert np.mean(ids[was0] == 0) > 0.99                      # the moved leaf kept whole
    new = ids[len(now[0]):len(now[0]) + len(now[1])]
    assert len(np.unique(new)) == 1 and new[0] not in (0, 1)   # its neighbour on its own
    assert np.all(ids[-len(now[2]):] == 1)
    # a view with the two apart: nothing to split, the moved one is found
    apart = dc_replace(sem, leaf_instance=np.r_[np.zeros(len(now[0]), int),
                                                np.full(len(now[1]), 2),
                                                np.ones(len(now[2]), int)])
    out, moved = SeparateMovedLeaves(apart, [before])
    assert moved == [0] and out is apart
    # a leaf nowhere near the moved one's rest: not found
    assert SeparateMovedLeaves(apart, [before + [0.0, 0.0, 0.3]])[1] == []


def dc_replace(obj, **kw):
    import dataclasses
    return dataclasses.replace(obj, **kw)


def test_the_next_leaf_over_a_fruit_is_one_not_moved_that_hides_enough():
    from lmap_drake.planning.targets import NextLeafOccluders
    occ = {"visible": 0.3, "leaves": [{"leaf_id": 4, "gain": 0.5},
                                      {"leaf_id": 2, "gain": 0.2}]}
    assert NextLeafOccluders(occ, [4], 0.1)["leaves"] == [{"leaf_id": 2, "gain": 0.2}]
    assert NextLeafOccluders(occ, [4], 0.25) is None
    assert NextLeafOccluders(occ, [4, 2], 0.0) is None
    assert NextLeafOccluders(occ, [], 0.1)["leaves"][0]["leaf_id"] == 4


def test_a_moved_leaf_segmented_in_pieces_is_moved_as_a_whole():
    from lmap_drake.planning.targets import SeparateMovedLeaves
    _, leaves = _plant()
    piece = leaves[0][:, 2] > 0.30
    now = np.vstack(leaves)
    ids = np.r_[np.where(piece, 0, 5), np.ones(len(leaves[1]), int),
                np.full(len(leaves[2]), 2)]
    sem = SemanticScene(leaf_points_W=now, leaf_instance=ids, X_WC=X_WC)
    _, moved = SeparateMovedLeaves(sem, [leaves[0]], other_leaf_points_W=[np.vstack(leaves[1:])])
    assert moved == [0, 5]


def test_a_leaf_hiding_only_what_a_view_has_shown_gains_nothing():
    """``seen_before_W``: the fruit's points from earlier views. Fruit A's
    left half (leaf 0) was shown by an earlier view: leaf 0 then gains
    almost nothing, leaf 1 what it gained before, and ``visible`` counts the
    shown half."""
    plant, _ = _plant()
    A = plant.fruits[0]
    plain = OccludingLeaves(A, plant, X_WC)
    gain = {d["leaf_id"]: d["gain"] for d in plain["leaves"]}
    left = A.vertices_W[(A.vertices_W[:, 0] < 0.445) & (A.vertices_W[:, 1] < 0)]
    seen = OccludingLeaves(A, plant, X_WC, seen_before_W=left)
    after = {d["leaf_id"]: d["gain"] for d in seen["leaves"]}
    assert after.get(0, 0.0) < 0.1 < gain[0] and abs(after[1] - gain[1]) < 0.05, (gain, after)
    assert seen["visible"] > plain["visible"] + 0.5 * gain[0]
    np.testing.assert_allclose(seen["seen_before_W"], left)
    # nothing shown before: the same as without
    none = OccludingLeaves(A, plant, X_WC, seen_before_W=np.zeros((0, 3)))
    assert none["leaves"] == plain["leaves"] and none["visible"] == plain["visible"]


def _single_scene(plant, k=0):
    """The single-fruit path's scene: every leaf point as the leaf, the
    fruit ``k`` the target, the other fruits obstacles."""
    from lmap_drake.types import SceneEstimate
    return SceneEstimate(semantic=plant.semantic, fruit=plant.fruits[k],
                         other_fruits=[f for m, f in enumerate(plant.fruits) if m != k])


def test_the_single_fruit_path_moves_an_occluder_of_its_fruit_not_every_leaf():
    from types import SimpleNamespace
    from lmap_drake.planning.targets import OccluderScene
    plant, leaves = _plant()
    cfg = SimpleNamespace(visibility_voxel=0.003, min_visibility_gain=0.05)
    occ = OccludingLeaves(plant.fruits[1], plant, X_WC)
    scene, why = OccluderScene(_single_scene(plant, 1), X_WC, cfg)
    assert why == ""
    # B's leaf is leaf 2: the others are obstacles, not part of the grasped leaf
    assert occ["leaves"][0]["leaf_id"] == 2
    assert np.array_equal(scene.semantic.leaf_points_W, leaves[2])
    assert len(scene.other_leaves_W) == len(leaves[0]) + len(leaves[1])
    # A: one of its two half-occluders, the one hiding more
    scene_a, _ = OccluderScene(_single_scene(plant, 0), X_WC, cfg)
    best = OccludingLeaves(plant.fruits[0], plant, X_WC)["leaves"][0]["leaf_id"]
    assert np.array_equal(scene_a.semantic.leaf_points_W, leaves[best])


def test_the_single_fruit_path_is_unchanged_with_one_leaf_and_says_when_no_leaf_hides():
    import dataclasses as dc
    from types import SimpleNamespace
    from lmap_drake.planning.targets import OccluderScene
    plant, leaves = _plant()
    cfg = SimpleNamespace(visibility_voxel=0.003, min_visibility_gain=0.05)
    one = dc.replace(plant.semantic, leaf_instance=np.zeros(len(plant.semantic.leaf_instance),
                                                            int))
    scene = _single_scene(dc.replace(plant, semantic=one), 1)
    same, why = OccluderScene(scene, X_WC, cfg)
    assert same is scene and why == ""
    # leaves far to the side of B hide nothing of it: nothing to move, said so
    far = dc.replace(plant.semantic, leaf_points_W=np.vstack(leaves[:2]) + [[-0.3, 0, 0]],
                     leaf_instance=plant.semantic.leaf_instance[:len(np.vstack(leaves[:2]))])
    scene = _single_scene(dc.replace(plant, semantic=far), 1)
    none, why = OccluderScene(scene, X_WC, cfg)
    assert "no leaf alone hides the fruit" in why
    assert len(none.semantic.leaf_points_W) == 0 and len(none.other_leaves_W) == len(
        far.leaf_points_W)


def test_a_phantom_fruit_is_no_target():
    from types import SimpleNamespace
    from lmap_drake.planning.targets import FruitImplausible, FruitOrder
    plant, _ = _plant()
    A = plant.fruits[0]
    pts = plant.semantic.fruit_points_W[plant.semantic.fruit_instance == 4]
    assert FruitImplausible(A, pts) == ""
    # a leaf patch completed as a fruit: its points far from the surface
    assert "from the completed surface" in FruitImplausible(A, pts + [0, -0.02, 0])
    # a completed 'fruit' the size of a melon
    huge = _fruit([0.45, 0.0, 0.30], r=0.07)
    assert "outside a pepper's" in FruitImplausible(huge, pts)
    cfg = SimpleNamespace(visibility_voxel=0.003, min_visibility_gain=0.02,
                          early_stop_fraction=0.95)
    plant.fruits[0] = huge
    order, occ = FruitOrder(plant, X_WC, cfg)
    assert 0 not in order and "implausible" in occ[0] and 1 in order


def _occluding_leaves_by_resplatting(fruit, plant, min_gain=0.02):
    """``OccludingLeaves`` as it was first written: the plant's leaves but
    one splatted again for every leaf (the reference for the fast form)."""
    from lmap_drake.planning.context import FruitSurfaceSamples
    from lmap_drake.planning.visibility import VisibilityModel
    sem = plant.semantic
    vis = VisibilityModel(X_WC, FruitSurfaceSamples(fruit), 0.003, None)
    n_max = int(vis.max_seen.sum())
    leaf_W, leaf_id = sem.leaf_points_W, sem.leaf_instance
    base = vis.ZBuffer(np.vstack([sem.branch_points_W.reshape(-1, 3)]
                                 + [f.vertices_W for f in plant.fruits if f is not fruit]))
    known = vis.Seen(leaf_W, base)
    out = []
    for j in np.unique(leaf_id[leaf_id >= 0]):
        gain = int(np.count_nonzero(vis.Seen(leaf_W[leaf_id != j], base) & ~known)) / n_max
        if gain >= min_gain:
            out.append({"leaf_id": int(j), "gain": float(gain)})
    return known.sum() / n_max, sorted(out, key=lambda d: -d["gain"])


def test_occluding_leaves_give_the_same_gains_as_splatting_every_leaf_but_one():
    plant, leaves = _plant()
    # many small leaves, some unassigned points, leaves behind and beside
    rng = np.random.default_rng(3)
    extra = [_plate(0.40 + 0.05 * i, 0.25 + 0.03 * (i % 3), 0.012, 0.012,
                    y=-0.05 - 0.01 * (i % 4)) for i in range(9)]
    pts = np.vstack([plant.semantic.leaf_points_W] + extra)
    ids = np.concatenate([plant.semantic.leaf_instance]
                         + [np.full(len(p), 3 + i) for i, p in enumerate(extra)])
    ids[rng.random(len(ids)) < 0.02] = -1
    import dataclasses as dc
    plant = dc.replace(plant, semantic=dc.replace(plant.semantic, leaf_points_W=pts,
                                                  leaf_instance=ids))
    for fruit in plant.fruits:
        got = OccludingLeaves(fruit, plant, X_WC, min_gain=0.0, min_points=1)
        visible, leaves_ref = _occluding_leaves_by_resplatting(fruit, plant, min_gain=0.0)
        assert got["visible"] == visible
        assert got["leaves"] == leaves_ref
        assert any(d["gain"] > 0 for d in got["leaves"])


def _confidence_cfg(min_conf):
    from types import SimpleNamespace
    return SimpleNamespace(visibility_voxel=0.003, min_visibility_gain=0.02,
                           early_stop_fraction=0.95, min_fruit_confidence=min_conf)


def test_a_fruit_instance_below_the_confidence_bar_is_no_target_but_an_occluder():
    import dataclasses as dc
    from lmap_drake.planning.targets import FruitOrder, SkippedFruits
    plant, _ = _plant()
    sem = dc.replace(plant.semantic, fruit_confidence={4: 0.31, 7: 0.93})
    plant = dc.replace(plant, semantic=sem)
    order, occ = FruitOrder(plant, X_WC, _confidence_cfg(0.5))
    assert 0 not in order and 1 in order
    assert "segmentation confidence 0.31 below planner.min_fruit_confidence 0.5" == \
        occ[0]["implausible"]
    assert occ[0]["confidence"] == 0.31 and occ[1]["confidence"] == 0.93
    skipped = SkippedFruits(plant, occ)
    assert [(s["fruit_id"], s["confidence"]) for s in skipped] == [(4, 0.31)]
    assert "below planner.min_fruit_confidence" in skipped[0]["why"]
    # the skipped fruit still hides the other one: B's visibility is as before
    _, occ_all = FruitOrder(plant, X_WC, _confidence_cfg(0.0))
    assert occ[1]["visible"] == occ_all[1]["visible"]
    # confidence 0 is perception's leaf-patch veto, and the reason says so
    plant = dc.replace(plant, semantic=dc.replace(sem, fruit_confidence={4: 0.0, 7: 0.93}))
    order, occ = FruitOrder(plant, X_WC, _confidence_cfg(0.5))
    assert 0 not in order and "a patch of leaf, perception.fruit_leaf_patches" in \
        occ[0]["implausible"]
    # 0 takes every instance; no confidence given counts as a fruit
    assert set(FruitOrder(plant, X_WC, _confidence_cfg(0.0))[0]) == {0, 1}
    bare = dc.replace(plant, semantic=dc.replace(plant.semantic, fruit_confidence={}))
    assert set(FruitOrder(bare, X_WC, _confidence_cfg(0.99))[0]) == {0, 1}
