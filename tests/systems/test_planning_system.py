"""ActionCandidates -> DeformationPrediction -> ActionSelection wired in a
Diagram on a synthetic scene: a leaf plate hanging from a branch in front of
a spherical fruit (the fruit estimate is exact)."""
import numpy as np
import pytest
import trimesh
from pydrake.systems.framework import DiagramBuilder

from lmap_drake.scenario import Scenario
from lmap_drake.systems.deformation import DeformationPrediction
from lmap_drake.systems.planning import ActionCandidates, ActionSelection
from lmap_drake.types import BranchEstimate, FruitEstimate, SceneEstimate, SemanticScene

CENTER = np.array([0.44, 0.0, 0.32])


def _scene(leaf_offset=np.zeros(3)) -> SceneEstimate:
    g = np.arange(-0.04, 0.04, 0.003)
    u, v = np.meshgrid(g, np.arange(-0.035, 0.035, 0.003))
    leaf = np.c_[CENTER[0] + u.ravel(), np.full(u.size, -0.065), CENTER[2] + v.ravel()]
    leaf = leaf + leaf_offset
    z = np.arange(0.15, 0.55, 0.004)
    branch = np.c_[np.full(len(z), 0.5), np.full(len(z), -0.006), z]
    # petiole: leaf top edge to the branch
    t = np.linspace(0, 1, 15)[:, None]
    petiole = (1 - t) * (leaf[np.argmax(leaf[:, 0] + leaf[:, 2])]) + t * [0.5, -0.006, 0.37]
    sphere = trimesh.creation.icosphere(3, radius=0.035).apply_translation(CENTER)
    fruit = FruitEstimate(vertices_W=sphere.vertices, faces=sphere.faces, X_WO=np.eye(4),
                          latent=np.zeros(0), center_W=CENTER, peduncle_axis_W=np.array([0, 0, 1.]),
                          sdf_W=lambda p: np.linalg.norm(p - CENTER, axis=1) - 0.035)
    cyl = trimesh.creation.cylinder(0.006, segment=[[0.5, 0, 0.1], [0.5, 0, 0.6]])
    branch_est = BranchEstimate(cyl.vertices, cyl.faces, branch, np.array([0, 0, 1.0]))
    sem = SemanticScene(branch_points_W=branch, leaf_points_W=np.vstack([leaf, petiole]),
                        fruit_points_W=sphere.vertices[sphere.vertices[:, 1] < -0.02],
                        X_WC=_X_WC())
    return SceneEstimate(semantic=sem, branch=branch_est, fruit=fruit)


def _X_WC():
    s = Scenario()
    return s.cameras["camera0"].X_PB.GetDeterministicValue().GetAsMatrix4()


def _plan(scene, energy_weight=1.0, max_energy=None, force_action=None, planner=None):
    s = Scenario()
    s.planner.num_grasps = 6
    s.planner.distances = [0.04, 0.08]
    s.planner.max_pull_distance = 0.0     # the pull cap has its own test
    s.planner.arc_lever_reference = 0.0   # so has the arc cap
    for k, v in (planner or {}).items():
        setattr(s.planner, k, v)
    if force_action is not None:
        s.planner.force_action = force_action
    if max_energy is not None:
        s.planner.max_energy_per_node = max_energy
    s.planner.energy_weight = energy_weight
    b = DiagramBuilder()
    cand = b.AddNamedSystem("action_candidates", ActionCandidates(s))
    deform = b.AddNamedSystem("deformation_prediction", DeformationPrediction(s.deformation))
    select = b.AddNamedSystem("action_selection", ActionSelection(s, cand))
    b.Connect(cand.GetOutputPort("scene_estimate"), deform.GetInputPort("scene_estimate"))
    b.Connect(cand.GetOutputPort("actions"), deform.GetInputPort("actions"))
    b.Connect(cand.GetOutputPort("candidate_set"), select.GetInputPort("candidate_set"))
    b.Connect(deform.GetOutputPort("predictions"), select.GetInputPort("predictions"))
    b.ExportInput(cand.GetInputPort("scene_estimate"), "scene_estimate")
    q = b.ExportInput(cand.GetInputPort("ur5.position"), "q")
    b.ConnectInput(q, select.GetInputPort("ur5.position"))
    b.ExportOutput(select.GetOutputPort("plan"), "plan")
    d = b.Build()
    ctx = d.CreateDefaultContext()
    d.GetInputPort("scene_estimate").FixValue(ctx, scene)
    d.GetInputPort("q").FixValue(ctx, s.robot.initial_q)
    return d.GetOutputPort("plan").Eval(ctx)


def test_diagram_plans_an_action_that_reveals_the_fruit():
    plan = _plan(_scene())
    assert plan.status == "ok", plan.message
    c = plan.chosen
    assert c.feasible and c.q_pulled is not None and np.isfinite(c.energy)
    assert c.seen > plan.seen_init + 0.5 * (plan.seen_max - plan.seen_init)
    rows = [x.Row() for x in plan.candidates]
    assert any(not r["feasible"] for r in rows) and all("reason" in r for r in rows)
    assert set(plan.timings) >= {"generation_collision_s", "deformation_s", "visibility_s"}


def test_energy_cap_rejects_risky_actions():
    free = _plan(_scene(), max_energy=0.0)              # no cap
    e = sorted(c.EnergyPerNode() for c in free.candidates if c.feasible)
    assert len(e) > 3
    cap = e[len(e) // 2]
    capped = _plan(_scene(), max_energy=cap)
    assert capped.status == "ok"
    ok = [c for c in capped.candidates if c.feasible]
    assert ok and all(c.EnergyPerNode() <= cap for c in ok)
    rejected = [c for c in capped.candidates if "above max_energy_per_node" in c.reason]
    assert rejected and all(c.EnergyPerNode() > cap for c in rejected)
    assert capped.chosen.EnergyPerNode() <= cap
    assert all(c.num_leaf_nodes > 10 for c in ok)
    # The score is normalised before the cap filters: the capped choice is the
    # uncapped plan's best-scoring action under the cap.
    key = lambda c: (c.action.grasp_id, c.action.direction_id, c.action.distance)
    best = max((c for c in free.candidates if c.feasible and c.EnergyPerNode() <= cap),
               key=lambda c: c.score)
    assert key(capped.chosen) == key(best)
    none_left = _plan(_scene(), max_energy=0.5 * e[0])
    assert none_left.status == "no_feasible_action" and "above max_energy_per_node" in none_left.message


def test_force_action_executes_the_named_candidate_whatever_its_score():
    free = _plan(_scene(), max_energy=0.0)
    key = lambda c: [c.action.grasp_id, c.action.direction_id, c.action.distance]
    # The worst-scoring feasible action, and one the energy cap would reject.
    worst = min((c for c in free.candidates if c.feasible), key=lambda c: c.score)
    forced = _plan(_scene(), max_energy=0.0, force_action=key(worst))
    assert forced.status == "ok" and key(forced.chosen) == key(worst)
    assert forced.chosen.seen == worst.seen and "forced action" in forced.message
    assert key(free.chosen) != key(worst)
    e = sorted(c.EnergyPerNode() for c in free.candidates if c.feasible)
    risky = max((c for c in free.candidates if c.feasible), key=lambda c: c.EnergyPerNode())
    capped = _plan(_scene(), max_energy=e[0] * 1.01, force_action=key(risky))
    assert capped.status == "ok" and key(capped.chosen) == key(risky)
    assert "above max_energy_per_node" in capped.chosen.reason
    assert capped.chosen.seen >= 0 and capped.chosen.q_pulled is not None
    # Robot-check failures and unknown candidates are refused, with the reason.
    failed = next(c for c in free.candidates if c.deformed_leaf_W is None)
    refused = _plan(_scene(), force_action=key(failed))
    assert refused.status == "no_feasible_action" and refused.chosen is None
    assert failed.reason.split(" (")[0] in refused.message
    missing = _plan(_scene(), force_action=[99, 0, 0.04])
    assert missing.status == "no_feasible_action" and "not among" in missing.message


def test_no_action_needed_when_the_leaf_is_aside():
    plan = _plan(_scene(leaf_offset=np.array([-0.2, 0, 0])))
    assert plan.status == "no_action_needed"
    assert plan.chosen is None


def test_no_fruit():
    scene = _scene()
    scene.fruit = None
    plan = _plan(scene)
    assert plan.status == "no_fruit" and plan.chosen is None


def test_plan_offers_hinge_arcs_with_the_petiole_term():
    plan = _plan(_scene(), max_energy=0.0)
    assert plan.status == "ok", plan.message
    # The hinge: where the petiole meets the branch.
    assert np.linalg.norm(plan.hinge_W - [0.5, -0.006, 0.37]) < 0.01
    arcs = [c for c in plan.candidates if c.action.family == "arc"]
    pulls = [c for c in plan.candidates if c.action.family == "pull"]
    assert arcs and pulls and all(c.action.direction_id >= 100 for c in arcs)
    k = Scenario().planner.hinge_bending_weight
    for c in (x for x in plan.candidates if x.feasible):
        bend = k * np.radians(c.hinge_deg) ** 2
        assert np.isclose(c.EnergyPerNode(), c.arap_energy / c.num_leaf_nodes + bend)
        row = c.Row()
        assert row["family"] == c.action.family and row["hinge_deg"] is not None
    # No action may turn the leaf more than max_hinge_deg about the hinge.
    limited = _plan(_scene(), max_energy=0.0, planner={"max_hinge_deg": 20.0})
    turned = [c for c in limited.candidates if np.isfinite(c.hinge_deg) and c.hinge_deg > 20]
    assert turned and all("max_hinge_deg 20" in c.reason for c in turned)
    assert limited.status != "ok" or limited.chosen.hinge_deg <= 20.0
    # An arc keeps the grasp's distance to the hinge; its turn is its angle.
    a = next(c for c in arcs if c.feasible)
    assert np.isclose(a.hinge_deg, np.rad2deg(a.action.angle), atol=0.5)
    # No action may pull the grasp farther from the hinge than the limit:
    # some pulls are refused for it, no arc is, and nothing chosen does it.
    tight = _plan(_scene(), max_energy=0.0, planner={"max_tether_elongation": 0.01,
                                                     "max_hinge_deg": 90.0})

    def tether(c):
        return (np.linalg.norm(c.action.p_WG + c.action.dp_W - tight.hinge_W)
                - np.linalg.norm(c.action.p_WG - tight.hinge_W))
    pulled = [c for c in tight.candidates if "max_tether_elongation 0.01" in c.reason]
    assert pulled and all(c.action.family == "pull" and tether(c) > 0.01 for c in pulled)
    assert tight.status != "ok" or tether(tight.chosen) <= 0.01


def test_a_straight_pull_is_capped_by_its_lever_to_the_attachment(monkeypatch):
    """No pull longer than max_pull_distance at a 10 cm grasp-attachment
    lever, scaled by (lever / 10 cm)^2, is chosen; the capped pulls still
    count in the score's normalisation (the same choice among the rest as
    without the cap); turns about the hinge are not capped. Each grasp also
    gets a pull of its own cap when that falls between two distances."""
    from lmap_drake.planning import candidates
    from lmap_drake.planning.energy import PULL_LEVER_REFERENCE
    distances = [0.02, 0.04, 0.08]
    with_cap = _plan(_scene(), planner={"distances": distances, "max_pull_distance": 0.03})
    extra = [c for c in with_cap.candidates if c.action.family == "pull"
             and min(abs(c.action.distance - d) for d in distances) > 1e-6]
    assert extra
    for c in extra:
        lever = np.linalg.norm(c.action.p_WG - with_cap.hinge_W)
        cap = 0.03 * (lever / PULL_LEVER_REFERENCE) ** 2
        assert cap - 0.001 <= c.action.distance <= cap       # the cap, floored to the mm
        assert "max_pull_distance" not in c.reason
    # The veto alone, on the same candidates as the free planner's:
    monkeypatch.setattr(candidates, "PullDistances", lambda cfg, p, h: sorted(cfg.distances))
    capped = _plan(_scene(), planner={"distances": distances, "max_pull_distance": 0.03})
    free = _plan(_scene(), planner={"distances": distances})
    n_capped = 0
    for c in capped.candidates:
        if c.action.family != "pull" or c.score != c.score:     # unscored: failed before
            continue
        lever = np.linalg.norm(c.action.p_WG - capped.hinge_W)
        over = c.action.distance > 0.03 * (lever / PULL_LEVER_REFERENCE) ** 2 + 1e-9
        assert over == ("max_pull_distance 0.03" in c.reason)
        n_capped += over
    assert n_capped > 0
    assert capped.status == "ok" and "max_pull_distance" not in capped.chosen.reason
    # the scores are the uncapped planner's: the cap only vetoes
    def key(c):
        return (c.action.grasp_id, c.action.direction_id, round(c.action.distance, 4),
                round(c.action.angle, 4))
    s_free = {key(c): c.score for c in free.candidates}
    assert len(s_free) == len(free.candidates) == len(capped.candidates)
    for c in capped.candidates:
        assert np.isclose(c.score, s_free[key(c)], equal_nan=True)
    if free.chosen.action.family != "pull" or free.chosen.action.distance <= 0.02:
        assert capped.chosen.action.Describe() == free.chosen.action.Describe()
    assert any(c.action.family == "arc" and c.action.distance > 0.04 and c.feasible
               for c in capped.candidates)


def test_an_arc_is_capped_by_its_lever_to_the_attachment():
    """No arc wider than 45 deg x lever / arc_lever_reference turns the leaf
    (a short lever needs a larger force for the same turn of the petiole);
    the capped arcs carry the reason and keep their scores (a veto, as for
    pulls); pulls and twists are not capped by it."""
    from lmap_drake.planning.energy import ARC_REFERENCE_DEG
    free = _plan(_scene())
    arcs = [c for c in free.candidates if c.action.family == "arc" and c.score == c.score]
    levers = [np.linalg.norm(c.action.p_WG - free.hinge_W) for c in arcs]
    ref = 1.05 * max(levers)       # every 45 deg arc over the cap, the 15 deg ones not
    capped = _plan(_scene(), planner={"arc_lever_reference": float(ref)})
    def key(c):
        return (c.action.grasp_id, c.action.direction_id, round(c.action.distance, 4),
                round(c.action.angle, 4))
    s_free = {key(c): c for c in free.candidates}
    assert len(s_free) == len(free.candidates) == len(capped.candidates)
    n_capped = 0
    for c in capped.candidates:
        f = s_free[key(c)]
        assert np.isclose(c.score, f.score, equal_nan=True)
        if c.score != c.score:       # unscored: failed before the veto
            continue
        over = False
        if c.action.family == "arc":
            lever = np.linalg.norm(c.action.p_WG - capped.hinge_W)
            widest = ARC_REFERENCE_DEG * min(1.0, lever / ref)
            over = np.degrees(abs(c.action.angle)) > widest + 1e-6
        assert over == ("arc_lever_reference" in c.reason), c.reason
        assert not over or not c.feasible
        n_capped += over
    assert n_capped > 0
    assert capped.status == "ok" and "arc_lever_reference" not in capped.chosen.reason
    if capped.chosen.action.family == "arc":
        assert np.degrees(abs(capped.chosen.action.angle)) < ARC_REFERENCE_DEG


def test_the_arm_may_not_push_another_leaf_at_a_moved_pose():
    """A leaf that is not held is an obstacle for the arm at the moved
    poses too (four_fruits: the wrist pressed a neighbouring leaf 30-100 N
    through the hold and the carry-back)."""
    import dataclasses as dc

    from lmap_drake.planning.robot_model import RobotModel
    plain = _plan(_scene(), max_energy=0.0)
    c = max((c for c in plain.candidates if c.feasible), key=lambda c: np.linalg.norm(
        c.q_pulled - c.q_grasp))
    robot = RobotModel(Scenario().robot.X_WB.GetDeterministicValue())
    moved = robot.SurfacePoints(c.q_pulled)
    ap = c.approach
    q0 = np.asarray(Scenario().robot.initial_q, float)
    approach_qs = ([q0 + f * (ap.via - q0) for f in np.linspace(0, 1, 8)]
                   + list(ap.to_ready) + list(ap.to_pregrasp) + list(ap.to_grasp))
    on_approach = np.vstack([robot.SurfacePoints(q, 0.05) for q in approach_qs])
    # a neighbouring leaf where the arm is only after the motion
    from scipy.spatial import cKDTree
    far = cKDTree(on_approach).query(moved)[0] > 0.03
    assert far.sum() > 20
    other = moved[far][::max(1, int(far.sum()) // 200)]
    blocked = _plan(dc.replace(_scene(), other_leaves_W=other), max_energy=0.0)
    same = next(b for b in blocked.candidates if b.action.Describe() == c.action.Describe()
                and b.action.grasp_id == c.action.grasp_id
                and b.action.direction_id == c.action.direction_id)
    assert "robot-leaf (another leaf)" in same.reason
    assert not any("another leaf" in x.reason for x in plain.candidates)


def test_the_leaf_may_not_be_swung_into_a_branch():
    """The deformation graph does not collide the leaf with the branch: a
    shoot where the chosen action's predicted leaf ends rejects that action
    ("leaf-branch"; random multi-fruit plants: arcs and twists that pressed
    the held leaf into the main stem loaded its petiole 17-28 N). The same
    candidates and predictions are selected with and without the shoot, so
    only the check differs (a shoot in the arm's way would also change the
    robot checks, and with them the batch the deformation is solved in)."""
    import dataclasses as dc

    from lmap_drake.planning.selection import SelectFromPredictions
    s = Scenario()
    s.planner.num_grasps, s.planner.distances = 6, [0.04, 0.08]
    s.planner.max_pull_distance, s.planner.max_energy_per_node = 0.0, 0.0
    s.planner.check_leaf_branch = True
    b = DiagramBuilder()
    cand = b.AddNamedSystem("action_candidates", ActionCandidates(s))
    deform = b.AddNamedSystem("deformation_prediction", DeformationPrediction(s.deformation))
    b.Connect(cand.GetOutputPort("scene_estimate"), deform.GetInputPort("scene_estimate"))
    b.Connect(cand.GetOutputPort("actions"), deform.GetInputPort("actions"))
    d = b.Build()
    ctx = d.CreateDefaultContext()
    cand.GetInputPort("scene_estimate").FixValue(cand.GetMyContextFromRoot(ctx), _scene())
    q = np.asarray(s.robot.initial_q, float)
    cand.GetInputPort("ur5.position").FixValue(cand.GetMyContextFromRoot(ctx), q)
    cset = cand.GetOutputPort("candidate_set").Eval(cand.GetMyContextFromRoot(ctx))
    preds = list(deform.GetOutputPort("predictions").Eval(deform.GetMyContextFromRoot(ctx)))

    plain = SelectFromPredictions(cand.Context(cset.scene, q), cset, preds, s.planner)
    assert not any("leaf-branch" in c.reason for c in plain.candidates)
    c = plain.chosen
    rest = np.asarray(cset.scene.semantic.leaf_points_W, float)[:len(c.deformed_leaf_W)]
    moved = np.linalg.norm(c.deformed_leaf_W - rest, axis=1)
    k = int(np.argmax(moved))
    assert moved[k] > 0.02
    # a short shoot (4 mm radius) through where that leaf point ends,
    # across the way it came
    p = c.deformed_leaf_W[k]
    u = (p - rest[k]) / moved[k]
    side = np.cross(u, [0, 0, 1.0]) if abs(u[2]) < 0.9 else np.cross(u, [1.0, 0, 0])
    side /= np.linalg.norm(side)
    stub = trimesh.creation.cylinder(0.004, segment=[p - 0.01 * side, p + 0.01 * side])
    br = cset.scene.branch
    both = trimesh.util.concatenate([trimesh.Trimesh(br.vertices_W, br.faces), stub])
    scene = dc.replace(cset.scene, branch=dc.replace(br, vertices_W=both.vertices,
                                                     faces=both.faces))
    blocked = SelectFromPredictions(cand.Context(scene, q), cset, preds, s.planner)
    key = lambda x: (x.action.grasp_id, x.action.direction_id, x.action.Describe())  # noqa: E731
    same = next(x for x in blocked.candidates if key(x) == key(c))
    assert same.reason.startswith("leaf-branch"), same.reason
    assert blocked.chosen is not None and blocked.chosen is not same
    off = SelectFromPredictions(cand.Context(scene, q), cset, preds,
                                dc.replace(s.planner, check_leaf_branch=False))
    assert key(off.chosen) == key(c)


def HeldAfterShortPull():
    """(first plan: the least revealing 4 cm pull, forced; a PlanningContext
    whose leaf is that pull's predicted leaf, at its joints; the scenario;
    the HeldGrasp) for continuation tests."""
    first = _plan(_scene(), max_energy=0.0)
    short = min((c for c in first.candidates if c.feasible and c.action.family == "pull"
                 and np.isclose(c.action.distance, 0.04)), key=lambda c: c.seen)
    key = [short.action.grasp_id, short.action.direction_id, short.action.distance]
    first = _plan(_scene(), max_energy=0.0, force_action=key)
    s = Scenario()
    s.planner.continuation_families = ["pull", "arc", "twist"]
    s.planner.continue_after_pull = True
    s.planner.distances = [0.04, 0.08]
    s.planner.max_pull_distance = 0.0
    s.planner.max_energy_per_node = 0.0
    return (first, *_HeldContext(first, s))


def _HeldContext(first, s):
    """(a PlanningContext whose leaf is ``first``'s chosen prediction, at
    its joints; the scenario ``s``; the HeldGrasp after it)."""
    import dataclasses as dc

    from lmap_drake.planning.context import PlanningContext
    from lmap_drake.planning.continuation import HeldGrasp
    from lmap_drake.planning.robot_model import RobotModel
    scene = _scene()
    moved = dc.replace(scene.semantic, leaf_points_W=first.chosen.deformed_leaf_W)
    ctx = PlanningContext(dc.replace(scene, semantic=moved), _X_WC(),
                          RobotModel(s.robot.X_WB.GetDeterministicValue()),
                          first.chosen.q_pulled)
    return ctx, s, HeldGrasp.After([first])


def test_no_continuation_turns_the_leaf_past_the_largest_arc():
    """After a 45-degree arc (the largest arc), a re-plan may turn the held
    leaf back or sideways but not farther: every twist on top of it (an
    equivalent turn above 45) is refused by max_replan_turn_deg, while a
    first motion keeps max_hinge_deg; a re-plan limit of 50 lets them
    through."""
    import dataclasses as dc

    from lmap_drake.planning.continuation import PlanContinuation
    s = Scenario()
    assert max(s.planner.arc_angles_deg) == s.planner.max_replan_turn_deg == 45.0
    assert s.planner.max_hinge_deg == 50.0
    first = _plan(_scene(), max_energy=0.0)
    # the least revealing 45-degree arc (after it, more is worth showing)
    arc = min((c for c in first.candidates if c.feasible and c.action.family == "arc"
               and np.isclose(np.rad2deg(c.action.angle), 45.0)), key=lambda c: c.seen)
    first = _plan(_scene(), max_energy=0.0, force_action=[
        arc.action.grasp_id, arc.action.direction_id, arc.action.distance])
    assert first.chosen.action.family == "arc"
    # first motions: the limit is max_hinge_deg
    assert all("max_replan_turn_deg" not in c.reason for c in first.candidates)
    s.planner.max_energy_per_node = 0.0
    s.planner.min_replan_gain = 0.0
    ctx, _, held = _HeldContext(first, s)

    def twists(planner):
        cont = PlanContinuation(ctx, planner, s.deformation, held)
        return cont, [c for c in cont.candidates if c.action.family == "twist"
                      and np.isfinite(c.hinge_deg)]
    cont, tw = twists(s.planner)
    assert tw and all(c.hinge_deg > 45.0 and "max_replan_turn_deg 45" in c.reason for c in tw)
    assert cont.chosen is None or cont.chosen.hinge_deg <= 45.0
    _, old = twists(dc.replace(s.planner, max_replan_turn_deg=50.0))
    assert any(c.hinge_deg < 50.0 and "turns the leaf" not in c.reason for c in old)


def test_continuation_from_the_held_leaf():
    """After a short pull the planner continues from where the gripper
    holds the leaf: every candidate starts at the held pose, the IK starts
    from the held joints, the energy cap sees the motions' summed energy,
    and a leaf already out of the way needs nothing more."""
    import dataclasses as dc

    from lmap_drake.planning.context import PlanningContext
    from lmap_drake.planning.continuation import PlanContinuation
    first, ctx, s, held = HeldAfterShortPull()
    a = first.chosen.action
    assert np.allclose(held.p_WG, a.p_WG + a.dp_W) and held.motions == 1
    scene = _scene()
    cont = PlanContinuation(ctx, s.planner, s.deformation, held)
    assert cont.status in ("ok", "no_action_needed"), cont.message
    assert cont.candidates or cont.status == "no_action_needed"
    for c in cont.candidates:
        assert np.allclose(c.action.p_WG, held.p_WG) and np.allclose(c.action.R_WG, held.R_WG)
        assert c.approach is None
    assert {c.action.family for c in cont.candidates} == {"pull", "arc", "twist"}
    # by default a re-plan only turns the held leaf (no straight pulls)
    turns = PlanContinuation(ctx, dc.replace(s.planner, continuation_families=["arc", "twist"]),
                             s.deformation, held)
    assert turns.candidates and {c.action.family for c in turns.candidates} <= {"arc", "twist"}
    assert Scenario().planner.continuation_families == ["arc", "twist"]
    # by default a straight pull is the last motion: nothing is planned after it
    assert held.families == ("pull",) and not Scenario().planner.continue_after_pull
    after_pull = PlanContinuation(ctx, dc.replace(s.planner, continue_after_pull=False),
                                  s.deformation, held)
    assert after_pull.status == "no_feasible_action" and not after_pull.candidates
    assert "continue_after_pull" in after_pull.message
    gain = s.planner.min_replan_gain * cont.seen_max
    assert all(c.seen >= cont.seen_init + gain for c in cont.candidates if c.feasible)
    assert any("not above the current" in c.reason for c in cont.candidates)
    if cont.status == "ok":
        assert cont.chosen.feasible and cont.chosen.seen >= 0
        # A cap below the energy already spent leaves nothing to do.
        s.planner.max_energy_per_node = 0.99 * held.energy_per_node
        capped = PlanContinuation(ctx, s.planner, s.deformation, held)
        assert capped.status == "no_feasible_action", capped.message
    # The robot holding the leaf occludes too: moving the leaf aside shows
    # more of the fruit, but not all of it.
    aside = dc.replace(scene.semantic, leaf_points_W=scene.semantic.leaf_points_W
                       + [-0.2, 0.0, 0.0])
    done = PlanContinuation(PlanningContext(dc.replace(scene, semantic=aside), ctx.X_WC,
                                            ctx.robot, ctx.q_current),
                            s.planner, s.deformation, held)
    assert done.seen_init > cont.seen_init
    robot_free = PlanContinuation(PlanningContext(dc.replace(scene, semantic=aside), ctx.X_WC,
                                                  ctx.robot, s.robot.initial_q),
                                  s.planner, s.deformation, held)
    assert robot_free.seen_init > done.seen_init


def test_a_plan_below_the_visibility_margin_is_not_ok_and_the_counts_cover_every_check():
    from lmap_drake.episode.records import PlanRecord
    ok = _plan(_scene())
    assert ok.status == "ok"
    gain = (ok.chosen.seen - ok.seen_init) / ok.seen_max
    assert gain >= 0.05        # the default margin
    # a margin above the best gain: no action is ok, every one says why
    strict = _plan(_scene(), planner={"min_visibility_gain": min(1.0, gain + 0.01)})
    assert strict.status == "no_feasible_action" and strict.chosen is None
    assert any("not above the current" in c.reason for c in strict.candidates)
    rec = PlanRecord(strict)
    assert rec["num_feasible"] == 0
    assert sum(rec["rejected"].values()) == rec["num_candidates"]
    assert any("not above the current" in k for k in rec["rejected"])


def test_the_most_seen_fruit_below_the_confidence_bar_is_no_target():
    scene = _scene()
    n = len(scene.semantic.fruit_points_W)
    scene.semantic.fruit_instance = np.zeros(n, np.int64)
    scene.semantic.fruit_confidence = {0: 0.42}
    plan = _plan(scene)
    assert plan.status == "no_fruit" and plan.chosen is None
    assert "fruit instance 0 (the most seen) is no target: segmentation confidence 0.42 " \
           "below planner.min_fruit_confidence 0.75" == plan.message
    # the bar lowered, the same scene plans
    assert _plan(scene, planner={"min_fruit_confidence": 0.4}).status == "ok"
