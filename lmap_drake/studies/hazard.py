"""Does the planner's prediction rank petiole loading and strain as the FEM
plant world does, for straight pulls, hinge arcs and twists?

    python scripts/eval_hazard_prediction.py --out out/hazard.json
    python scripts/eval_hazard_prediction.py --out h.json \
        --scenarios small_leaf_thin_branch_round_red_heavy --pull_distances 0.04 0.08

Per scenario (default: two small-leaf and two large-leaf scenes of
diagrams/suite.yaml):

1. ``PlantWorldSim`` settles 0.3 s; camera0 is segmented
   (``--segmenter``, default ``perception.segmenter`` of the scenario, the
   realistic one) into a ``SemanticScene``; ``OracleSceneEstimate`` adds the
   exact branch (a deformation/hazard study, not a perception study);
   ``AttachLeaf`` adds the virtual petiole when the petiole is unseen.
2. The scripted tip grasp (``ApproachAndGrasp``) as in
   ``scripts/eval_deformation_vs_fem.py``.
3. From that grasp: pulls along the 6 axial and 8 diagonal directions that
   pass the branch-angle rule, by ``--pull_distances``, and arcs about the
   estimated hinge (``planning.attachment.EstimateHinge``) around
   ``--num_axes`` axes by ``--arc_angles``, and twists about the
   hinge-grasp line by +-``--twist_angles``. All are predicted in one
   ``PredictDeformations`` call; each is executed on its own fork of the
   grasped world (``PlanActionPath``, the controller's pull speed, then a
   0.3 s hold) and scored by the plant world: maximum petiole force and
   strain percentile over the motion, final fruit visibility.
4. Predicted measures per action: the ARAP energy per leaf node (the
   planner's damage measure) and ``planning.hazard`` measures of petiole
   loading. Spearman rank correlations between each predicted measure and
   each FEM measure, per scenario and pooled, per family and over both.

Multi-fruit plants (``plant_scene.kind: multi``, e.g. a file from
``scripts/make_suite.py --multi --random N --seed S``) are studied from the
grasps the planner itself chooses (``EvaluateMultiScenario``): the first
view is segmented and completed as in an episode, every fruit is planned,
the best grasp of each weighed leaf is approached and closed in the plant
world, and straight pulls, arcs and twists are executed from it (arcs and
twists about the planner's own hinge estimate). Rows carry the predicted
tether elongation (the planner's hinge estimate) and the true one (the
grasped leaf's petiole base); ``grasps`` gives each grasp's hinge error.

    python scripts/make_suite.py --multi --random 3 --seed 5151 --out out/rm.yaml
    python scripts/eval_hazard_prediction.py --out out/hazard_multi.json \
        --scenario_file out/rm.yaml --scenarios random_multi_5151_000 \
        --families pull --pull_distances 0.015 0.025 0.035 0.045

Writes JSON after every scenario (partial results survive an interruption).
"""
from __future__ import annotations

import dataclasses as dc
import json
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import yaml
from tqdm import tqdm

from lmap_drake.deformation.action import (Action, HingeAxes, MakeArcActions, MakeTwistActions,
                                           PullDirections)
from lmap_drake.deformation.predict import PredictDeformations, UnmodelledGrasp
from lmap_drake.paths import REPO_ROOT
from lmap_drake.deformation.config import DeformationConfig
from lmap_drake.perception.observe import SemanticSceneFromImages
from lmap_drake.planning.candidates import DirectionsForGrasp
from lmap_drake.planning.collision import LeafCollisionReason
from lmap_drake.planning.hazard import AttachmentMisfit, HazardMeasures, TetherElongation
from lmap_drake.planning.attachment import AttachLeaf, EstimateHinge
from lmap_drake.planning.candidates import GraspActions
from lmap_drake.planning.context import PlanningContext
from lmap_drake.planning.energy import EquivalentTurnDeg, HingeRotationDeg, PetioleBendingEnergy
from lmap_drake.planning.motion import MotionError, PlanActionPath, TimeJointPath
from lmap_drake.planning.targets import FruitOrder, PlanTarget, TargetScene
from lmap_drake.plants.multi import MULTI_KINDS
from lmap_drake.plants.plant_sim import PlantWorldSim
from lmap_drake.plants.scripted import ApproachAndGrasp, OracleSceneEstimate
from lmap_drake.planning.config import PlannerConfig
from lmap_drake.scenario import LoadScenario
from lmap_drake.shape.completion import CompletePlant
from lmap_drake.shape.deepsdf import LoadDecoder
from lmap_drake.studies.deformation_vs_fem import LeafMeshWorkaround, Spearman
from lmap_drake.systems.arm_motion import ROTATION_SPEED
from lmap_drake.systems.planning import ImageTangents

DEFAULT_SCENARIOS = ["small_leaf_thin_branch_round_red_heavy",
                     "small_leaf_thin_branch_striped_red_partial",
                     "large_leaf_thick_branch_round_red_heavy",
                     "large_leaf_thick_branch_striped_red_partial"]
PREDICTED = ("energy_per_node", "planner_energy_per_node", "petiole_stretch",
             "tether_elongation_m")
MEASURED = ("petiole_force_max_N", "strain_percentile_max")


@dc.dataclass
class HazardStudyOptions:
    """The study's settings (the flags of ``scripts/eval_hazard_prediction.py``)."""
    out: str = ""                    # JSON file written after every scenario
    scenario_file: Path = REPO_ROOT / "diagrams" / "suite.yaml"
    scenarios: list = dc.field(default_factory=lambda: list(DEFAULT_SCENARIOS))
    pull_distances: list = dc.field(default_factory=lambda: [0.04, 0.08])    # m
    arc_angles: list = dc.field(default_factory=lambda: [30.0, 60.0])        # deg
    twist_angles: list = dc.field(default_factory=lambda: [30.0, 60.0])      # deg
    families: list = dc.field(default_factory=lambda: ["pull", "arc", "twist"])
    pool: list = dc.field(default_factory=list)     # earlier runs' JSON pooled with this one
    num_axes: int = 8
    then_twist: list = dc.field(default_factory=list)   # deg: continuation twists after arcs
    then_arc: list = dc.field(default_factory=list)     # deg: continuation arcs after arcs
    then_turn_band: list = dc.field(default_factory=list)   # (LO, HI] deg of the continuations
    speed: float = 0.03              # m/s: TCP speed
    hold: float = 0.3                # s
    segmenter: str = ""              # '' = the scenario's
    repredict: bool = False          # only re-run the predictions of ``out``
    deformation_text: str = "{}"     # with ``repredict``: deformation overrides
    hinge_bending_weight: float | None = None   # with ``repredict`` (None: the planner's)


def PlannerEnergy(a, p, hinge, weight: float, torsion_ratio: float | None = None) -> dict:
    """The ARAP energy per leaf node and the planner's predicted energy per
    node (ARAP plus the petiole term on the equivalent turn: bending, and a
    twist's torsion by ``planner.petiole_torsion_ratio``)."""
    ratio = PlannerConfig().petiole_torsion_ratio if torsion_ratio is None else torsion_ratio
    e = p.energy / max(1, int((p.node_kind == 0).sum()))
    deg = EquivalentTurnDeg(HingeRotationDeg(hinge, a.p_WG, a.p_WG + a.dp_W),
                            abs(a.angle) if a.family == "twist" else 0.0, ratio)
    return {"energy_per_node": e, "hinge_deg": deg,
            "planner_energy_per_node": e + PetioleBendingEnergy(deg, weight)}


def _Advance(world, action, speed: float, hold: float) -> list:
    """Run ``action`` on ``world`` (in place) at the controller's timing,
    then hold; the outcome samples taken meanwhile."""
    n0 = len(world.samples)
    q_path = PlanActionPath(world.robot, action, world.q_cmd)
    # the controller's timing: the pull speed along the path, turns at most
    # ROTATION_SPEED (a twist turns in place)
    traj = TimeJointPath(world.time, world.q_cmd, q_path, 0.3, 0.01,
                         max(1.0, action.path_length / speed,
                             abs(action.angle) / ROTATION_SPEED))
    world.AdvanceTo(traj.end_time(), traj)
    world.Hold(hold)
    return world.samples[n0:] + [world.Sample()]


def _Measures(world, s: list) -> dict:
    return {"petiole_force_max_N": max(x.petiole_force for x in s),
            "strain_percentile_max": max(x.strain_percentile for x in s),
            "fruit_penetration_max_m": max(x.fruit_penetration for x in s),
            "visibility_final": world.Visibility()}


def _Execute(grasped, action, speed: float, hold: float) -> dict:
    world = grasped.Fork()
    return _Measures(world, _Advance(world, action, speed, hold))


def _ExecuteThen(grasped, action, hinge, attach, twist_deg: list[float], arc_deg: list[float],
                num_axes: int, speed: float, hold: float, torsion_ratio: float,
                turn_band: tuple = ()) -> tuple[dict, list[dict]]:
    """``action`` (an arc) on a fork of ``grasped``, then from where it ends
    each continuation as the planner's re-planning would make it: twists
    (both senses of every angle in ``twist_deg``) about the line from
    ``hinge`` through the grasp, and arcs about ``hinge`` (``num_axes``
    axes, every angle in ``arc_deg``). The arc's own measures, and one row
    per continuation: the planner's equivalent turn from the first grasp
    (estimated hinge, ``hinge_reference_W``), the true bend (about
    ``attach``) and the FEM measures over both motions together. With
    ``turn_band`` (lo, hi), only continuations whose equivalent turn lies in
    (lo, hi] are executed."""
    world = grasped.Fork()
    s_arc = _Advance(world, action, speed, hold)
    first = _Measures(world, s_arc)
    X = world.X_WT()
    p1, R1 = X.translation(), X.rotation().matrix()
    bend = HingeRotationDeg(hinge, action.p_WG, p1)
    true_bend = HingeRotationDeg(attach, action.p_WG, p1)
    rows = []
    more = list(MakeTwistActions(p1, R1, hinge, np.deg2rad(twist_deg)))
    if arc_deg:
        more += MakeArcActions(p1, R1, hinge, HingeAxes(p1, hinge, num_axes), np.deg2rad(arc_deg))
    for t in more:
        end = t.p_WG + t.dp_W
        bend_t = HingeRotationDeg(hinge, action.p_WG, end)
        turn = EquivalentTurnDeg(bend_t, abs(t.angle) if t.family == "twist" else 0.0,
                                 torsion_ratio)
        if turn_band and not turn_band[0] < turn <= turn_band[1]:
            continue
        w = world.Fork()
        r = {"family": f"arc+{t.family}", "direction_id": action.direction_id,
             "twist_direction_id": t.direction_id, "distance_m": round(action.distance, 4),
             "angle_deg": round(np.rad2deg(action.angle), 1),
             "twist_deg": round(np.rad2deg(t.angle), 1),
             "bend_deg_executed": round(bend, 1), "true_bend_deg": round(true_bend, 1),
             "bend_deg_after": round(bend_t, 1),
             "true_bend_deg_after": round(HingeRotationDeg(attach, action.p_WG, end), 1),
             "equivalent_turn_deg": round(turn, 1),
             "arc_petiole_force_max_N": first["petiole_force_max_N"]}
        try:
            r.update(_Measures(w, s_arc + _Advance(w, t, speed, hold)))
        except RuntimeError as err:   # a MotionError, or the simulation giving up
            r["error"] = str(err)
        rows.append(r)
    return first, rows


def EvaluateScenario(scenario, args: HazardStudyOptions, log) -> dict:
    scenario, mesh_note = LeafMeshWorkaround(scenario)
    world = PlantWorldSim(scenario, progress=lambda m: None)
    world.Hold(0.3)
    vis0 = world.Visibility()
    im = world.Images()
    pcfg = scenario.perception if not args.segmenter else dc.replace(
        scenario.perception, segmenter=args.segmenter)
    sem = SemanticSceneFromImages(im["rgb_image"], im["depth_image"], im["label_image"],
                                  scenario.cameras["camera0"], pcfg)
    scene = OracleSceneEstimate(world, sem)
    scene, _ = AttachLeaf(scene, scenario.deformation)
    leaf = np.asarray(sem.leaf_points_W, float).reshape(-1, 3)
    branch = np.vstack([np.asarray(sem.branch_points_W, float).reshape(-1, 3),
                        scene.branch.samples_W])
    leaf_in = np.vstack([leaf, scene.leaf_attachment_W])
    pull = scenario.plant_scene.pull
    for extra in (0.0, 0.015, 0.03):
        try:
            ApproachAndGrasp(world, dc.replace(pull, grasp_from_tip=pull.grasp_from_tip + extra))
            break
        except MotionError:
            if extra == 0.03:
                raise
    X_WT = world.X_WT()
    p_WG, R_WG = X_WT.translation(), X_WT.rotation().matrix()
    hinge = EstimateHinge(leaf, branch)
    dirs, ids = DirectionsForGrasp(p_WG, branch, 120.0, PullDirections())
    actions = []
    if "pull" in args.families:
        actions += [Action(p_WG, R_WG, d * u, direction_id=int(j))
                    for u, j in zip(dirs, ids) for d in args.pull_distances]
    if "arc" in args.families:
        actions += MakeArcActions(p_WG, R_WG, hinge, HingeAxes(p_WG, hinge, args.num_axes),
                                  np.deg2rad(args.arc_angles))
    if "twist" in args.families:
        actions += MakeTwistActions(p_WG, R_WG, hinge, np.deg2rad(args.twist_angles))
    np.savez(Path(args.out).with_suffix(f".{scenario_name_of(scenario)}.npz"),
             leaf_in=leaf_in, branch=branch, p_WG=p_WG, R_WG=R_WG, hinge=hinge)
    preds = PredictDeformations(leaf_in, branch, actions, scenario.deformation)
    measures = HazardMeasures(actions, preds, hinge)
    rows = []
    for a, p, m in tqdm(list(zip(actions, preds, measures)), desc=scenario_name_of(scenario),
                        unit="action", file=sys.stderr):
        r = {"family": a.family, "direction_id": a.direction_id,
             "distance_m": round(a.distance, 4), "angle_deg": round(np.rad2deg(a.angle), 1)}
        r.update(PlannerEnergy(a, p, hinge, scenario.planner.hinge_bending_weight))
        r.update(m)
        try:
            r.update(_Execute(world, a, args.speed, args.hold))
        except MotionError as err:
            r["error"] = str(err)
        rows.append(r)
    return {"rows": rows, "visibility_initial": vis0, "hinge_W": hinge.tolist(),
            "true_attach_W": np.asarray(world.model.leaf_attach_W).tolist(),
            "mesh_note": mesh_note}


def EvaluateMultiScenario(scenario, args: HazardStudyOptions, log) -> dict:
    """``plant_scene.kind: multi``: the grasps the planner itself would use.
    The first view is segmented and completed as in an episode
    (``CompletePlant``), every fruit is planned (``PlanTarget``) and, per
    weighed leaf option, the grasp of its best candidate (the chosen one, or
    the best by score among those only the hazard limits rejected) is
    approached and closed in the plant world. From it, straight pulls (the
    branch-angle rule, ``--pull_distances``), arcs and twists about the
    planner's hinge estimate (``--arc_angles``, ``--twist_angles``; as
    ``--families`` selects) run on forks, each scored by the FEM (petiole
    force and blade strain). ``leaf_fruit`` and ``leaf_branch`` give the
    planner's leaf checks on each prediction ('' = passes);
    ``leaf_branch_away_from_hinge`` a variant that counts every leaf point
    farther than 2 cm from the hinge estimate, touching or not.
    ``tether_elongation_m`` is measured against the planner's own hinge
    estimate (``plan.hinge_W``), ``true_tether_elongation_m`` against the
    grasped leaf's true petiole base; ``true_misfit_m`` (``true_misfit_strain``
    over the true lever) is how far the action moves that base in the
    gripper's frame (``planning.hazard.AttachmentMisfit``)."""
    world = PlantWorldSim(scenario, progress=lambda m: None)
    world.Hold(0.3)
    im = world.Images()
    pcfg = scenario.perception if not args.segmenter else dc.replace(
        scenario.perception, segmenter=args.segmenter)
    sem = SemanticSceneFromImages(im["rgb_image"], im["depth_image"], im["label_image"],
                                  scenario.cameras["camera0"], pcfg)
    dec, mean, _ = LoadDecoder(scenario.shape.weights_file)
    plant = CompletePlant(sem, dec, mean, scenario.shape.ssc, "ssc",
                          scenario.shape.free_space_voxel, scenario.shape.branch,
                          leaf_split_angle_deg=scenario.shape.leaf_split_angle_deg,
                          min_fruit_points=scenario.shape.min_fruit_points)
    X_WC = scenario.cameras["camera0"].X_PB.GetDeterministicValue().GetAsMatrix4()
    tan = ImageTangents(scenario)
    order, occ = FruitOrder(plant, X_WC, scenario.planner, tan)
    hazard_reasons = ("pulls the grasp", "turns the leaf", "beyond the distance",
                      "straight pull from a grasp")   # (the last: max_pull_distance)
    grasps, rows = [], []
    notes = []
    for k in order:
        t = PlanTarget(plant, k, X_WC, world.robot, world.q_cmd, scenario.planner,
                       scenario.deformation, tan, occluders=occ[k])
        for lid, plan in t.options:
            ok = [c for c in plan.candidates if c.approach is not None and (
                c.feasible or any(h in c.reason for h in hazard_reasons))]
            if not ok or plan.hinge_W is None:
                notes.append(f"fruit {k} leaf {lid}: no grasp to try ({plan.status})")
                continue
            best = plan.chosen or max(ok, key=lambda c: (c.n_vis, -c.action.distance))
            key = (tuple(np.round(best.action.p_WG, 3)), lid)
            if key not in [g[0] for g in grasps]:
                grasps.append((key, best, np.asarray(plan.hinge_W, float), k))
    log(f"{len(grasps)} planner grasps; " + "; ".join(notes))
    dirs_all = PullDirections()
    out_grasps = []
    for (_, lid), best, hinge, k in grasps:
        g = world.Fork()
        ap = best.approach
        try:
            g.SetGripper(ap.opening, 0.0)
            g.MoveJoints([ap.via], speed_fraction=0.8)
            g.MoveJoints(ap.to_ready, speed_fraction=0.5)
            g.MoveJoints(ap.to_pregrasp, speed_fraction=0.5)
            g.MoveJoints(ap.to_grasp, speed_fraction=0.15)
            g.CloseOnLeaf()
            gs = g.Grasp()
        except (RuntimeError, MotionError) as err:
            notes.append(f"fruit {k} leaf {lid}: grasp failed: {err}")
            continue
        true_leaf = gs.grasp.leaf
        X_WT = g.X_WT()
        p_WG, R_WG = X_WT.translation(), X_WT.rotation().matrix()
        attach = np.asarray(world.model.leaves[true_leaf].attach_W, float)
        # the planner's own inputs for this target and leaf
        ctx = PlanningContext(TargetScene(plant, k, lid), X_WC, world.robot, world.q_cmd, tan,
                              fruit_shapes=scenario.planner.fruit_shapes)
        # the planner's own generator (arcs and twists about its hinge
        # estimate), with the study's distances and angles
        study = dc.replace(scenario.planner, action_families=list(args.families),
                           distances=list(args.pull_distances), num_arc_axes=args.num_axes,
                           twist_angles_deg=list(args.twist_angles))
        actions = GraspActions(ctx, study, SimpleNamespace(p_WG=p_WG, R_WG=R_WG, grasp_id=0),
                                hinge, np.deg2rad(args.arc_angles),
                                dirs_all[:scenario.planner.num_directions])
        attached, _ = AttachLeaf(ctx.scene, scenario.deformation)
        leaf_in = np.vstack([ctx.leaf_W, attached.leaf_attachment_W])
        preds = PredictDeformations(leaf_in, ctx.branch_all_W, actions, scenario.deformation,
                                    skip_unmodelled=True)
        modelled = [not isinstance(p, UnmodelledGrasp) for p in preds]
        measures = iter(HazardMeasures([a for a, m in zip(actions, modelled) if m],
                                       [p for p, m in zip(preds, modelled) if m], hinge))
        info = {"fruit": int(k), "leaf_estimate": int(lid), "leaf_true": int(true_leaf),
                "p_WG": p_WG.round(4).tolist(), "hinge_W": hinge.round(4).tolist(),
                "true_attach_W": attach.round(4).tolist(),
                "hinge_error_m": round(float(np.linalg.norm(hinge - attach)), 4),
                "lever_m": round(float(np.linalg.norm(p_WG - hinge)), 4),   # MaxPullDistance's L
                "chosen_action": best.action.Describe()}
        out_grasps.append(info)
        name = f"{scenario_name_of(scenario)} fruit {k} leaf {lid}"
        for a, p, ok in tqdm(list(zip(actions, preds, modelled)), desc=name, unit="pull",
                             file=sys.stderr):
            misfit = AttachmentMisfit(a, attach)
            r = {"family": a.family, "direction_id": a.direction_id,
                 "distance_m": round(a.distance, 4), "angle_deg": round(np.rad2deg(a.angle), 1),
                 "grasp": len(out_grasps) - 1,
                 "true_tether_elongation_m": TetherElongation(a.p_WG, a.p_WG + a.dp_W, attach),
                 # the true attachment's misfit in the gripper's frame, over
                 # the true lever (see planning.hazard)
                 "true_misfit_m": misfit,
                 "true_misfit_strain": misfit / max(
                     float(np.linalg.norm(a.p_WG - attach)), 1e-6)}
            if ok:
                r.update(PlannerEnergy(a, p, hinge, scenario.planner.hinge_bending_weight))
                r.update(next(measures))
                # the planner's leaf checks on this prediction ('' = passes)
                moved = np.asarray(p.leaf_points_W)[:len(ctx.leaf_W)]
                margin = scenario.planner.collision_margin
                r["leaf_fruit"] = LeafCollisionReason(ctx.leaf_W, moved, ctx.fruit_sdf, margin,
                                                      ctx.fruit_box)
                r["leaf_branch"] = LeafCollisionReason(ctx.leaf_W, moved, ctx.branch_distance,
                                                       margin, ctx.branch_box, what="branch",
                                                       ignore_touching=True)
                far = np.linalg.norm(ctx.leaf_W - hinge, axis=1) > 0.02
                r["leaf_branch_away_from_hinge"] = LeafCollisionReason(
                    ctx.leaf_W[far], moved[far], ctx.branch_distance, margin, ctx.branch_box,
                    what="branch")
            else:   # the deformation graph cannot model it: the tether alone
                r.update({"energy_per_node": float("nan"), "planner_energy_per_node": float("nan"),
                          "hinge_deg": float("nan"), "petiole_stretch": float("nan"),
                          "tether_elongation_m": TetherElongation(a.p_WG, a.p_WG + a.dp_W,
                                                                  hinge)})
            more = []
            try:
                if a.family == "arc" and (args.then_twist or args.then_arc):
                    first, more = _ExecuteThen(
                        g, a, hinge, attach, args.then_twist, args.then_arc, args.num_axes,
                        args.speed, args.hold, scenario.planner.petiole_torsion_ratio,
                        tuple(args.then_turn_band))
                    r.update(first)
                else:
                    r.update(_Execute(g, a, args.speed, args.hold))
            except MotionError as err:
                r["error"] = str(err)
            rows.append(r)
            rows += [dict(m, grasp=r["grasp"]) for m in more]
    return {"rows": rows, "grasps": out_grasps, "notes": notes}


def scenario_name_of(s) -> str:
    return getattr(s, "_name", "scenario")


def Correlations(rows: list[dict]) -> dict:
    out = {}
    for fam in ("all", "pull", "arc", "twist"):
        # (continuation rows, families 'arc+twist' and 'arc+arc', carry no predictions)
        sel = [r for r in rows if "error" not in r and "energy_per_node" in r
               and (fam == "all" or r["family"] == fam)]
        out[fam] = {"n": len(sel)}
        for pk in PREDICTED:
            for mk in MEASURED:
                out[fam][f"{pk}~{mk}"] = Spearman([r[pk] for r in sel], [r[mk] for r in sel])
    return out


def Repredict(path: str, deformation_text: str, hinge_bending_weight: float) -> dict:
    """Predictions again for the actions of an earlier run (its JSON and
    the inputs saved next to it), with ``deformation`` overrides; the FEM
    side is reused. Returns the correlations."""
    d = json.loads(Path(path).read_text())
    cfg = dc.replace(DeformationConfig(), **(yaml.safe_load(deformation_text) or {}))
    pooled, out = [], {}
    for name, sc in d["scenarios"].items():
        z = np.load(Path(path).with_suffix(f".{name}.npz"), allow_pickle=False)
        acts = []
        for r in sc["rows"]:
            if r["family"] == "twist":
                twists = MakeTwistActions(z["p_WG"], z["R_WG"], z["hinge"],
                                          [np.deg2rad(r["angle_deg"])])
                acts.append(twists[r["direction_id"] - 200])
            elif r["family"] == "arc":
                axes = HingeAxes(z["p_WG"], z["hinge"], d["config"]["num_axes"])
                acts += MakeArcActions(z["p_WG"], z["R_WG"], z["hinge"],
                                       axes[[r["direction_id"] - 100]],
                                       [np.deg2rad(r["angle_deg"])],
                                       axis_ids=[r["direction_id"] - 100])
            else:
                acts.append(Action(z["p_WG"], z["R_WG"],
                                   r["distance_m"] * PullDirections()[r["direction_id"]]))
        preds = PredictDeformations(z["leaf_in"], z["branch"], acts, cfg)
        for r, a, p, m in zip(sc["rows"], acts, preds, HazardMeasures(acts, preds, z["hinge"])):
            r.update(PlannerEnergy(a, p, z["hinge"], hinge_bending_weight))
            r.update(m)
        out[name] = Correlations(sc["rows"])
        pooled += sc["rows"]
    out["pooled"] = Correlations(pooled)
    d["repredicted"] = {"deformation_text": deformation_text,
                        "hinge_bending_weight": hinge_bending_weight, "correlation": out}
    Path(path).with_suffix(".repredicted.json").write_text(json.dumps(d, indent=1))
    return out


def RunHazardStudy(a: HazardStudyOptions) -> int:
    """The study on every scenario of ``a`` (see the module docstring), or
    with ``a.repredict`` only the predictions of ``a.out`` again; writes
    ``a.out`` after every scenario. Returns the exit code (0)."""
    if a.repredict:
        w = (PlannerConfig().hinge_bending_weight if a.hinge_bending_weight is None
             else a.hinge_bending_weight)
        print(json.dumps(Repredict(a.out, a.deformation_text, w)["pooled"], indent=1))
        return 0
    out = {"config": {k: (str(v) if isinstance(v, Path) else v) for k, v in ((f.name, getattr(a, f.name)) for f in dc.fields(a))},
           "scenarios": {}}
    pooled = []
    for name in a.scenarios:
        t0 = time.perf_counter()
        s = LoadScenario(filename=str(a.scenario_file), scenario_name=name)
        s._name = name
        evaluate = EvaluateMultiScenario if s.plant_scene.kind in MULTI_KINDS else EvaluateScenario
        res = evaluate(s, a, lambda m: print(m, file=sys.stderr))
        res["correlation"] = Correlations(res["rows"])
        res["seconds"] = round(time.perf_counter() - t0, 1)
        out["scenarios"][name] = res
        pooled += res["rows"]
        out["pooled"] = Correlations(pooled)
        Path(a.out).write_text(json.dumps(out, indent=1))
        print(f"{name}: {len(res['rows'])} actions in {res['seconds']} s; "
              f"{json.dumps(res['correlation']['all'])}", file=sys.stderr)
    if a.pool:
        # this run's actions joined with earlier runs' (same scenes, same grasp)
        combined: dict = {}
        for f in a.pool:
            for name, sc in json.loads(Path(f).read_text())["scenarios"].items():
                combined.setdefault(name, []).extend(sc["rows"])
        for name, sc in out["scenarios"].items():
            combined.setdefault(name, []).extend(sc["rows"])
        out["pooled_with_earlier"] = {
            "files": list(a.pool),
            "per_scene": {n: Correlations(r) for n, r in combined.items()},
            "all": Correlations([r for rows in combined.values() for r in rows])}
        Path(a.out).write_text(json.dumps(out, indent=1))
        print(json.dumps(out["pooled_with_earlier"]["all"], indent=1))
        return 0
    print(json.dumps(out["pooled"], indent=1))
    return 0
