"""Several fruits at diagram level: PlantPlanning (the next fruit, the leaf
to move) and the ArmController's sequencing, on a synthetic two-fruit plant
(fixed estimates, no station): fruit A behind one leaf, fruit B behind
another; the controller reveals one, releases, retreats, looks again,
plans the other, then ends when both are handled."""
import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from lmap_drake.scenario import Scenario
from lmap_drake.systems.arm_controller import ArmController, ControllerOptions
from lmap_drake.systems.planning import HeldLeaf, PlantPlanning
from lmap_drake.types import PlantEstimate, SceneEstimate, SemanticScene
from tests.planning.test_targets import _fruit
from tests.systems.test_planning_system import _scene


def TwoFruitPlant() -> PlantEstimate:
    """The planning tests' plant, and a second leaf and fruit 11 cm lower."""
    one = _scene()
    sem = one.semantic
    drop = np.array([0.0, 0.0, -0.11])
    leaf2 = sem.leaf_points_W + drop
    A = one.fruit
    B = _fruit(A.center_W + drop)
    fa, fb = sem.fruit_points_W, sem.fruit_points_W + drop
    plant_sem = SemanticScene(
        branch_points_W=sem.branch_points_W,
        leaf_points_W=np.vstack([sem.leaf_points_W, leaf2]),
        leaf_instance=np.r_[np.zeros(len(leaf2), int), np.ones(len(leaf2), int)],
        fruit_points_W=np.vstack([fa, fb]),
        fruit_instance=np.r_[np.full(len(fa), 3), np.full(len(fb), 5)], X_WC=sem.X_WC)
    return PlantEstimate(semantic=plant_sem, branch=one.branch, fruits=[A, B],
                         fruit_ids=[3, 5])


def _Scenario() -> Scenario:
    s = Scenario()
    s.planner.targets = "all"
    s.planner.num_grasps = 6
    s.planner.distances = [0.04, 0.08]
    s.planner.action_families = ["pull", "arc"]
    s.planner.max_replans = 0
    # one reveal per fruit: these tests are about the order of the fruits;
    # the plant estimate is fixed, so a second reveal would repeat the first
    # (second reveals have their own tests below)
    s.planner.max_reveals_per_fruit = 1
    return s


def _RunToEnd(s: Scenario, plant: PlantEstimate):
    """PlantPlanning + ArmController on the fixed ``plant`` estimate (no
    station), simulated until the controller finishes (at most 120 s); its
    final status."""
    b = DiagramBuilder()
    planner = b.AddNamedSystem("plant_planning", PlantPlanning(s))
    c = b.AddNamedSystem("arm_controller", ArmController(s, options=ControllerOptions(
        grasp_ack_required=False)))
    b.Connect(c.GetOutputPort("status"), planner.GetInputPort("status"))
    b.Connect(planner.GetOutputPort("plan"), c.GetInputPort("plan"))
    b.Connect(planner.GetOutputPort("scene_estimate"), c.GetInputPort("scene_estimate"))
    d = b.Build()
    sim = Simulator(d)
    ctx = sim.get_mutable_context()
    pc, cc = planner.GetMyMutableContextFromRoot(ctx), c.GetMyMutableContextFromRoot(ctx)
    planner.GetInputPort("plant_estimate").FixValue(pc, AbstractValue.Make(plant))
    planner.GetInputPort("ur5.position").FixValue(pc, s.robot.initial_q)
    c.GetInputPort("semantic_scene").FixValue(cc, AbstractValue.Make(SemanticScene()))
    c.GetInputPort("final_estimate").FixValue(cc, AbstractValue.Make(SceneEstimate(
        SemanticScene())))
    c.GetInputPort("ur5.state_estimated").FixValue(cc, np.r_[s.robot.initial_q, np.zeros(6)])
    c.GetInputPort("gripper.state_measured").FixValue(cc, [0.003, 0.0, 1.0])
    c.GetInputPort("views_fused").FixValue(cc, [10.0])
    while sim.get_context().get_time() < 120.0 and not c.Status(cc).finished:
        sim.AdvanceTo(sim.get_context().get_time() + 0.25)
    st = c.Status(cc)
    return st


def test_held_leaf_is_the_instance_at_the_gripper():
    plant = TwoFruitPlant()
    leaf = plant.semantic.leaf_points_W
    assert HeldLeaf(plant.semantic, leaf[-1]) == 1
    assert HeldLeaf(plant.semantic, leaf[0]) == 0
    assert HeldLeaf(SemanticScene(), leaf[0]) == -1


def test_fruits_are_revealed_one_after_another():
    s = _Scenario()
    plant = TwoFruitPlant()
    st = _RunToEnd(s, plant)
    assert st.mode == "done", st.message
    assert "every fruit is visible or handled" in st.message
    modes = [m for _, m in st.mode_log]
    assert modes.count("pull") == 2 and modes.count("retreat") == 2
    # a fresh view before each fruit, and a last one that finds nothing left
    assert modes.count("capture") == 3
    assert len(st.targets) == 2
    ids = [t["target"]["fruit_id"] for t in st.targets]
    assert sorted(ids) == [3, 5]
    for t in st.targets:
        assert t["outcome"].startswith("revealed")
        assert t["target"]["leaf_id"] in (0, 1) and t["target"]["why"]
        assert t["plan"].chosen is not None and t["t_end"] > t["t_start"]
    # each fruit's leaf is the one in front of it
    by_id = {t["target"]["fruit_id"]: t["target"]["leaf_id"] for t in st.targets}
    assert by_id == {3: 0, 5: 1}
    # the less visible fruit first
    vis = [t["target"]["visible_predicted"] for t in st.targets]
    assert vis[0] <= vis[1] + 1e-9


def test_a_fragment_of_a_handled_fruit_is_handled_too():
    """A later view completes a fragment of a revealed fruit on its own:
    its centre lies 4 cm from the target's (beyond ``SAME_FRUIT_DISTANCE``)
    but its points lie on the target's re-estimate, so it is not targeted
    again; the other fruit still is."""
    import dataclasses as dc
    import types

    from lmap_drake.systems.planning import SAME_FRUIT_DISTANCE, _Handled
    plant = TwoFruitPlant()
    A, B = plant.fruits
    record = {"target": {"center_W": A.center_W.tolist()},
              "final_estimate": SceneEstimate(plant.semantic, fruit=A)}
    status = types.SimpleNamespace(targets=[record])
    shift = np.array([0.0, 0.04, 0.0])
    assert np.linalg.norm(shift) > SAME_FRUIT_DISTANCE
    fragment = dc.replace(A, center_W=A.center_W + shift,
                          vertices_W=A.vertices_W + shift)
    assert _Handled(dc.replace(plant, fruits=[fragment, B]), status) == [True, False]
    # without the target's estimate only the centre distance is left
    record["final_estimate"] = None
    assert _Handled(dc.replace(plant, fruits=[fragment, B]), status) == [False, False]


def test_target_focus_is_the_current_targets_centre():
    import types

    from lmap_drake.systems.planning import TargetFocus
    focus = TargetFocus()
    ctx = focus.CreateDefaultContext()
    port = focus.GetInputPort("status")
    out = focus.GetOutputPort("target_center")
    plan = types.SimpleNamespace(target={"center_W": [0.5, -0.01, 0.3]})
    port.FixValue(ctx, AbstractValue.Make(types.SimpleNamespace(plan=plan)))
    assert np.allclose(out.Eval(ctx), [0.5, -0.01, 0.3])
    port.FixValue(ctx, AbstractValue.Make(types.SimpleNamespace(plan=None)))
    assert out.Eval(ctx) is None


def test_a_fruit_whose_motion_cannot_be_executed_is_skipped(monkeypatch):
    """The chosen motion of the first fruit has no joint path (IK fails
    along it): that fruit is recorded as such and the other is revealed;
    the episode is not aborted."""
    import lmap_drake.systems.arm_motion as ac
    from lmap_drake.planning.motion import MotionError
    real = ac.PlanActionPath
    calls = []

    def first_fails(*args, **kw):
        calls.append(1)
        if len(calls) == 1:
            raise MotionError("IK failed along the arc at [0.4 0.0 0.2]")
        return real(*args, **kw)
    monkeypatch.setattr(ac, "PlanActionPath", first_fails)
    s = _Scenario()
    plant = TwoFruitPlant()
    st = _RunToEnd(s, plant)
    assert st.mode == "done", st.message
    outcomes = [t["outcome"] for t in st.targets]
    assert len(outcomes) == 2
    assert outcomes[0].startswith("no_executable_path") and "IK failed" in outcomes[0]
    assert outcomes[1].startswith("revealed")
    modes = [m for _, m in st.mode_log]
    assert modes.count("pull") == 1 and "aborted" not in modes


def test_a_fruit_without_a_feasible_action_is_recorded_with_its_estimate(monkeypatch):
    """The first fruit has no leaf with a feasible action: its record keeps
    the estimate it was planned on (for its shape metrics), it is not
    planned again, and the other fruit is revealed."""
    import lmap_drake.planning.targets as targets
    real = targets.PlanTarget
    calls = []

    def first_infeasible(plant, k, *args, **kw):
        calls.append(k)
        if len(calls) == 1:
            occ = kw.get("occluders") or {"visible": 0.3, "leaves": []}
            return targets.TargetPlan(k, plant.fruit_ids[k], occ["visible"], occ["leaves"],
                                      why="no leaf has a feasible action")
        return real(plant, k, *args, **kw)
    monkeypatch.setattr(targets, "PlanTarget", first_infeasible)
    plant = TwoFruitPlant()
    st = _RunToEnd(_Scenario(), plant)
    assert st.mode == "done", st.message
    assert len(st.targets) == 2 and len(set(calls)) == 2
    first = st.targets[0]
    assert first["outcome"].startswith("no_feasible_action")
    assert first["target"]["leaf_id"] is None
    k = first["target"]["fruit_index"]
    for key in ("initial_estimate", "final_estimate"):      # (copies: Drake clones state)
        fruit = first[key].fruit
        assert fruit is not None and np.allclose(fruit.center_W, plant.fruits[k].center_W)
    assert st.targets[1]["outcome"].startswith("revealed")


def _FruitUnderTwoLeaves() -> PlantEstimate:
    """The planning tests' plant with its leaf twice, 3.5 cm higher and 3.5
    cm lower on the branch (the lower one 5 mm nearer the camera): each
    hides a part of the one fruit that the other does not."""
    one = _scene()
    sem = one.semantic
    upper = sem.leaf_points_W + [0.0, 0.0, 0.035]
    lower = sem.leaf_points_W + [0.0, -0.005, -0.035]
    plant_sem = SemanticScene(
        branch_points_W=sem.branch_points_W, leaf_points_W=np.vstack([upper, lower]),
        leaf_instance=np.r_[np.zeros(len(upper), int), np.ones(len(lower), int)],
        fruit_points_W=sem.fruit_points_W,
        fruit_instance=np.full(len(sem.fruit_points_W), 3), X_WC=sem.X_WC)
    return PlantEstimate(semantic=plant_sem, branch=one.branch, fruits=[one.fruit],
                         fruit_ids=[3])


def test_a_fruit_under_two_leaves_is_revealed_again_by_the_other_leaf():
    """With ``max_reveals_per_fruit: 2`` the fruit is revealed a second
    time, by the leaf not moved the first time, and its record says why;
    with 1 (the paper) once. (The estimate here is fixed: each view shows
    the same plant, so the leaf moved first is found where it was.)"""
    s = _Scenario()
    s.planner.max_reveals_per_fruit = 2
    s.planner.next_leaf_min_gain = 0.05
    st = _RunToEnd(s, _FruitUnderTwoLeaves())
    assert st.mode == "done", st.message
    assert len(st.targets) == 2, [t["outcome"] for t in st.targets]
    first, second = (t["target"] for t in st.targets)
    assert {first["leaf_id"], second["leaf_id"]} == {0, 1}
    assert first["reveal"] == 1 and second["reveal"] == 2
    assert second["moved_before"] == [first["leaf_id"]]
    assert second["why"].startswith("reveal 2 of this fruit")
    assert all(t["outcome"].startswith("revealed") for t in st.targets)
    s.planner.max_reveals_per_fruit = 1
    st = _RunToEnd(s, _FruitUnderTwoLeaves())
    assert st.mode == "done" and len(st.targets) == 1
    # what the other leaf alone hides is too little to go again for
    s.planner.max_reveals_per_fruit = 2
    s.planner.next_leaf_min_gain = 0.99
    assert len(_RunToEnd(s, _FruitUnderTwoLeaves()).targets) == 1


def test_the_reestimate_keeps_the_fruits_it_left_out_as_obstacles():
    """The focused re-estimate completes only the fruits near the target:
    the scene a further motion is planned on still has the far fruit (from
    the target's plan) as an obstacle, and not twice the near one. Without
    it the arm's wrist swung into a fruit 20 cm above the target during a
    continuation arc (206 N)."""
    import types

    from lmap_drake.systems.planning import TargetReestimate
    plant = TwoFruitPlant()
    A, B = plant.fruits
    focused = PlantEstimate(semantic=plant.semantic, branch=plant.branch, fruits=[A],
                            fruit_ids=[3])
    s = _Scenario()
    sys_ = TargetReestimate(s)
    ctx = sys_.CreateDefaultContext()
    sys_.GetInputPort("plant_estimate").FixValue(ctx, AbstractValue.Make(focused))
    sys_.GetInputPort("ur5.position").FixValue(ctx, s.robot.initial_q)
    plan = types.SimpleNamespace(target={"center_W": A.center_W.tolist()})
    planned = SceneEstimate(plant.semantic, fruit=A, other_fruits=[B, A])
    sys_.GetInputPort("status").FixValue(ctx, AbstractValue.Make(
        types.SimpleNamespace(plan=plan, initial_estimate=planned)))
    out = sys_.GetOutputPort("scene_estimate").Eval(ctx)
    # (Drake hands out copies: compare by centre)
    assert np.allclose(out.fruit.center_W, A.center_W)
    assert len(out.other_fruits) == 1 and np.allclose(out.other_fruits[0].center_W, B.center_W)
    sys_.GetInputPort("status").FixValue(ctx, AbstractValue.Make(
        types.SimpleNamespace(plan=plan, initial_estimate=None)))
    assert sys_.GetOutputPort("scene_estimate").Eval(ctx).other_fruits == []


def test_a_second_reveal_needs_a_leaf_not_moved_and_a_fruit_not_yet_shown():
    """Fruit A hides behind leaves 0 and 1, and leaf 0 was moved: leaf 1 is
    its next leaf, unless a view with leaf 0 held already showed 95 % of
    it, or the fruit may be revealed once only."""
    from lmap_drake.planning.result import PlanResult
    from lmap_drake.planning.targets import FruitOrder
    from lmap_drake.scenario import Scenario
    from lmap_drake.systems.planning import _PlantAfterMoves, _SecondReveals
    from tests.planning.test_targets import X_WC, _plant
    plant, leaves = _plant()
    cfg = Scenario().planner
    cfg.max_reveals_per_fruit = 2
    _, occ = FruitOrder(plant, X_WC, cfg)

    def target(seen):
        moved = SemanticScene(leaf_points_W=leaves[0], leaf_instance=np.zeros(len(leaves[0]),
                                                                              int))
        return {"motions": 1, "target": {"center_W": [0.45, 0.0, 0.3]},
                "initial_estimate": SceneEstimate(moved, other_leaves_W=np.vstack(leaves[1:])),
                "replan_results": [PlanResult("ok", "lmap", seen_init=seen, seen_max=100)]}
    def again(seen):
        per_fruit = [[target(seen)], []]
        _, moved = _PlantAfterMoves(plant, per_fruit)
        return _SecondReveals(per_fruit, moved, occ, cfg), moved
    out, moved = again(50)
    assert list(out) == [0]
    rest = out[0]
    assert moved[0] == [0] and [d["leaf_id"] for d in rest["leaves"]] == [1]
    assert again(97)[0] == {}
    cfg.max_reveals_per_fruit = 1
    assert again(50)[0] == {}


def test_a_moved_leaf_is_moved_again_only_for_surface_no_view_has_shown():
    """Fruit B hides behind leaf 2 alone, and leaf 2 was moved (no other
    leaf to try): with ``planner.reveal_moved_leaf_again`` leaf 2 is named
    again while it hides surface no view has shown, never when the views so
    far showed it, nor with the option off."""
    from lmap_drake.planning.targets import FruitOrder, OccludingLeaves
    from lmap_drake.scenario import Scenario
    from lmap_drake.systems.planning import _PlantAfterMoves, _SecondReveals
    from tests.planning.test_targets import X_WC, _plant
    plant, leaves = _plant()
    cfg = Scenario().planner
    cfg.max_reveals_per_fruit = 2
    _, occ = FruitOrder(plant, X_WC, cfg)
    B = plant.fruits[1]
    moved_sem = SemanticScene(leaf_points_W=leaves[2], leaf_instance=np.zeros(len(leaves[2]), int))
    t = {"motions": 1, "target": {"center_W": [0.6, 0.0, 0.3]},
         "initial_estimate": SceneEstimate(moved_sem, other_leaves_W=np.vstack(leaves[:2])),
         "replan_results": []}
    per_fruit = [[], [t]]
    _, moved = _PlantAfterMoves(plant, per_fruit)
    assert moved[1] == [2]

    def never_seen(shown):
        return lambda k: OccludingLeaves(plant.fruits[k], plant, X_WC, seen_before_W=shown)
    import trimesh
    dense = np.asarray(trimesh.creation.icosphere(5, 0.035).vertices) + B.center_W
    front = dense[dense[:, 1] < 0]           # the whole face toward the camera
    out = _SecondReveals(per_fruit, moved, occ, cfg, never_seen(front[front[:, 2] > 0.33]))
    assert [d["leaf_id"] for d in out[1]["leaves"]] == [2]
    assert len(out[1]["seen_before_W"])
    assert _SecondReveals(per_fruit, moved, occ, cfg, never_seen(front)) == {}
    cfg.reveal_moved_leaf_again = False
    assert _SecondReveals(per_fruit, moved, occ, cfg,
                          never_seen(front[front[:, 2] > 0.33])) == {}


def test_the_surface_shown_includes_the_views_with_the_leaf_held():
    """``_ShownFruitPoints``: fruit k's points in this view and in each
    handled target's re-estimate (the leaf held), not its first estimate's
    again."""
    from lmap_drake.systems.planning import _ShownFruitPoints
    from tests.planning.test_targets import _plant
    plant, _ = _plant()
    here = plant.semantic.fruit_points_W[plant.semantic.fruit_instance == 7]
    held = SceneEstimate(SemanticScene(fruit_points_W=np.array([[0.6, 0.03, 0.3]])))
    first = SceneEstimate(SemanticScene(fruit_points_W=np.array([[9.0, 9.0, 9.0]])))
    pts = _ShownFruitPoints(plant, 1, [{"initial_estimate": first, "final_estimate": held},
                                       {"initial_estimate": first, "final_estimate": first}])
    assert len(pts) == len(here) + 1 and [0.6, 0.03, 0.3] in pts.tolist()
    assert [9.0, 9.0, 9.0] not in pts.tolist()


def test_a_fruit_instance_perception_is_unsure_of_is_skipped_and_stays_an_obstacle():
    import dataclasses as dc
    from types import SimpleNamespace
    from lmap_drake.episode.records import PlanRecord
    s = _Scenario()
    plant = TwoFruitPlant()
    plant = dc.replace(plant, semantic=dc.replace(plant.semantic,
                                                  fruit_confidence={3: 0.31, 5: 0.95}))
    def planning(s):
        system = PlantPlanning(s)
        ctx = system.CreateDefaultContext()
        system.GetInputPort("plant_estimate").FixValue(ctx, plant)
        system.GetInputPort("ur5.position").FixValue(ctx, np.asarray(s.robot.initial_q, float))
        system.GetInputPort("status").FixValue(ctx, SimpleNamespace(targets=[]))
        return system, ctx
    system, ctx = planning(s)
    plan = system.GetOutputPort("plan").Eval(ctx)
    assert plan.target["fruit_id"] == 5
    [skipped] = plan.skipped_fruits
    assert skipped["fruit_id"] == 3 and skipped["confidence"] == 0.31
    assert "below planner.min_fruit_confidence 0.75" in skipped["why"]
    assert PlanRecord(plan)["skipped_fruits"] == plan.skipped_fruits       # in plan.json
    # the skipped fruit is an obstacle and occluder of the target's scene
    scene = system.GetOutputPort("scene_estimate").Eval(ctx)
    np.testing.assert_allclose(scene.fruit.center_W, plant.fruits[1].center_W)
    assert len(scene.other_fruits) == 1
    np.testing.assert_allclose(scene.other_fruits[0].center_W, plant.fruits[0].center_W)
    # every instance below the bar: nothing to plan, and plan.json says why
    s.planner.min_fruit_confidence = 0.99
    system, ctx2 = planning(s)
    none = system.GetOutputPort("plan").Eval(ctx2)
    assert none.status == "no_action_needed" and "is no target" in none.message
    assert [d["fruit_id"] for d in none.skipped_fruits] == [3, 5]
