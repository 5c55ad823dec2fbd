"""Leaf Manipulation Action Planning (paper Sec. III-C): candidates, IK and
collision checks, deformation prediction, visibility prediction and the
score argmax(norm N_vis - lambda norm E) over feasible actions; plus the
Random, Upward and Min-Overlap baselines. World frame W, metres, seconds."""
from __future__ import annotations

import dataclasses as dc
import json
import re
import time
from pathlib import Path

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix

from lmap_drake.deformation.action import (Action, DeformationError, HingeAxes, MakeArcActions,
                                          MakeTwistActions, PullDirections)
from lmap_drake.deformation.graph import FREE, BuildLeafGraph, MainLeafComponent, Voxelize
from lmap_drake.deformation.predict import PredictDeformations, UnmodelledGrasp
from lmap_drake.planning.candidates import DirectionsForGrasp, GraspCandidates, PlanningError
from lmap_drake.planning.collision import (BranchDistance, LeafCollisionReason,
                                           NearBox, RobotCollisionReason, UnionSdf)
from lmap_drake.planning.hazard import TetherElongation
from lmap_drake.planning.robot_model import SELF_MARGIN, RobotModel
from lmap_drake.planning.visibility import CountNewlySeen, VisibilityModel
from lmap_drake.scenario import DeformationConfig, PlannerConfig
from lmap_drake.types import SceneEstimate

# "stage_error": a stage of the planner (candidates, deformation prediction,
# selection) failed; ``message`` names the stage and the error.
STATUSES = ("ok", "no_action_needed", "no_feasible_action", "no_fruit", "stage_error")


@dc.dataclass
class Candidate:
    """One (grasp, direction, distance) action with its checks and scores."""
    action: Action
    distance_id: int
    q_pregrasp: np.ndarray | None = None
    q_grasp: np.ndarray | None = None
    q_pulled: np.ndarray | None = None
    approach: object = None       # planning.motion.ApproachPlan
    reason: str = ""              # empty = feasible
    energy: float = float("nan")  # predicted: ARAP + petiole bending (m^2, weighted)
    arap_energy: float = float("nan")   # the deformation graph's ARAP energy alone
    hinge_deg: float = float("nan")     # rotation of the grasp about the estimated hinge
    num_leaf_nodes: int = 0       # deformable nodes of the action's graph
    n_vis: int = -1
    seen: int = -1
    score: float = float("nan")
    deformed_leaf_W: np.ndarray | None = None
    # a second-chance grasp orientation (``GraspAlternatives``): approach
    # tilted this many degrees in the blade's plane, gripper turned 180 deg
    orientation: tuple | None = None        # (tilt_deg, turned) or None: as generated

    @property
    def feasible(self) -> bool:
        return self.reason == ""

    def EnergyPerNode(self) -> float | None:
        """Predicted energy per deformable (leaf) node, m^2 (the ARAP energy
        plus the petiole's bending, see ``PetioleBendingEnergy``): the energy's
        leaf-size-independent form, compared with ``max_energy_per_node``."""
        if np.isnan(self.energy) or self.num_leaf_nodes <= 0:
            return None
        return self.energy / self.num_leaf_nodes

    def Row(self) -> dict:
        a = self.action
        return {"grasp_id": a.grasp_id, "direction_id": a.direction_id, "family": a.family,
                "angle_deg": round(float(np.rad2deg(a.angle)), 3),
                "pivot_W": None if a.pivot_W is None else a.pivot_W.round(4).tolist(),
                "axis_W": None if a.axis_W is None else a.axis_W.round(4).tolist(),
                "distance": round(a.distance, 4), "p_WG": a.p_WG.round(4).tolist(),
                "dp_W": a.dp_W.round(4).tolist(), "feasible": self.feasible,
                "reason": self.reason, "energy": None if np.isnan(self.energy) else self.energy,
                "pregrasp_opening": (None if self.approach is None
                                     else round(self.approach.opening, 4)),
                "ready_distance": (None if self.approach is None
                                   else round(self.approach.ready_extra, 4)),
                "approach_tilt_deg": None if self.orientation is None else self.orientation[0],
                "gripper_turned": None if self.orientation is None else self.orientation[1],
                "energy_per_node": self.EnergyPerNode(),
                "arap_energy": None if np.isnan(self.arap_energy) else self.arap_energy,
                "hinge_deg": None if np.isnan(self.hinge_deg) else round(self.hinge_deg, 2),
                "n_vis": self.n_vis, "seen": self.seen,
                "score": None if np.isnan(self.score) else self.score}


@dc.dataclass
class PlanResult:
    """The planner's answer. ``status`` is one of ``STATUSES``; ``chosen``
    is set when status is 'ok'. Visibility counts are 3 mm fruit voxels."""
    status: str
    method: str
    chosen: Candidate | None = None
    candidates: list[Candidate] = dc.field(default_factory=list)
    dropped_grasps: list[dict] = dc.field(default_factory=list)
    seen_init: int = 0
    seen_max: int = 0
    timings: dict = dc.field(default_factory=dict)
    message: str = ""
    hinge_W: np.ndarray | None = None   # the arcs' pivot (estimated petiole attachment)
    # Several fruits (``planner.targets: all``): which fruit this plan is for
    # and which leaf it moves, and why (JSON-able; see systems.planning.PlantPlanning).
    target: dict | None = None

    def Summary(self) -> dict:
        out = {"status": self.status, "method": self.method, "message": self.message,
               "seen_init": self.seen_init, "seen_max": self.seen_max,
               "timings": self.timings, "num_candidates": len(self.candidates),
               "num_feasible": sum(c.feasible for c in self.candidates),
               "dropped_grasps": self.dropped_grasps,
               "hinge_W": None if self.hinge_W is None else np.round(self.hinge_W, 4).tolist()}
        if self.target is not None:
            out["target"] = self.target
        if self.chosen is not None:
            out["chosen"] = self.chosen.Row()
        return out

    def SaveJson(self, path: str | Path) -> None:
        data = self.Summary()
        data["candidates"] = [c.Row() for c in self.candidates]
        Path(path).write_text(json.dumps(data, indent=1))


@dc.dataclass
class PlanningContext:
    """Inputs shared by the planners: the scene estimate, the camera pose
    ``X_WC`` (4x4), the robot model and its current joints."""
    scene: SceneEstimate
    X_WC: np.ndarray
    robot: RobotModel
    q_current: np.ndarray
    # camera0's field of view as tangents (x_min, x_max, y_min, y_max) of the
    # optical frame; None = unbounded. Bounds the visibility model's grid.
    image_tan: tuple | None = None
    # the fruit's points observed in earlier views (W, m; a second reveal of
    # the same fruit): the surface they show counts as seen before any
    # action, so an action scores by what no view has shown (N_vis)
    seen_before_W: np.ndarray | None = None

    def __post_init__(self):
        sem = self.scene.semantic
        self.leaf_W = np.asarray(sem.leaf_points_W, float)
        self.branch_obs_W = np.asarray(sem.branch_points_W, float)
        branch = self.scene.branch
        self.branch_all_W = (np.vstack([self.branch_obs_W, branch.samples_W])
                             if branch is not None and len(branch.samples_W) else self.branch_obs_W)
        self.branch_distance = (BranchDistance(branch.vertices_W, branch.faces)
                                if branch is not None and len(branch.faces) else None)
        fruit = self.scene.fruit
        self.fruit_sdf = fruit.sdf_W if fruit is not None else None
        self.fruit_box = ((fruit.vertices_W.min(0), fruit.vertices_W.max(0))
                          if fruit is not None else None)
        # Several fruits: the robot and the moved leaf keep clear of every
        # one (the union's SDF is the minimum); only the target is revealed.
        others = [f for f in getattr(self.scene, "other_fruits", []) if f is not None]
        if fruit is not None and others:
            fruits = [fruit] + others
            self.fruit_sdf = UnionSdf([f.sdf_W for f in fruits],
                                      [(f.vertices_W.min(0), f.vertices_W.max(0))
                                       for f in fruits])
            V = np.vstack([f.vertices_W for f in fruits])
            self.fruit_box = (V.min(0), V.max(0))
        self.other_leaves_W = np.asarray(getattr(self.scene, "other_leaves_W", np.zeros((0, 3))),
                                         float).reshape(-1, 3)
        # What hides the target besides the leaf being moved (and the robot):
        # the branches, the other leaves and the other fruits.
        self.occluders_W = np.vstack([self.branch_obs_W, self.other_leaves_W]
                                     + [f.vertices_W for f in others])
        self.branch_box = ((branch.vertices_W.min(0), branch.vertices_W.max(0))
                           if branch is not None and len(branch.vertices_W) else None)
        self.p_WC = np.asarray(self.X_WC, float)[:3, 3]


def FruitSurfaceSamples(f) -> np.ndarray:
    """Even samples of a ``FruitEstimate``'s surface plus its vertices (W, m)."""
    import trimesh
    mesh = trimesh.Trimesh(f.vertices_W, f.faces, process=False)
    pts, _ = trimesh.sample.sample_surface_even(mesh, 6000, seed=0)
    return np.vstack([pts, f.vertices_W])


def _RobotPoseReason(robot, q: np.ndarray, half_open: float, points_W: np.ndarray,
                     ctx: PlanningContext, cfg: PlannerConfig, self_margin: float = 0.0
                     ) -> str:
    """'' if the robot at ``q`` (surface samples ``points_W``, an array or
    per geometry) is clear of itself (arm against gripper or arm; distant
    links by ``self_margin``) and keeps the margin from the fruit and the
    branch, else the reason."""
    pair = robot.SelfCollision(q, half_open, self_margin)
    if pair:
        return f"robot self-collision ({pair})"
    return RobotCollisionReason(points_W, ctx.fruit_sdf, ctx.branch_distance,
                                cfg.collision_margin, ctx.fruit_box, ctx.branch_box,
                                cfg.robot_fruit_margin)


def _LeafObstacles(ctx: PlanningContext, held: bool = True) -> tuple:
    """(KD-tree of the observed leaf points or None, their box (lo, hi)),
    built once per planning context (cached on it): every leaf (the
    approach's obstacles), or with ``held`` False only the leaves not held
    (``ctx.other_leaves_W``, the moved poses' obstacles)."""
    attr = "_leaf_obstacles" if held else "_other_leaf_obstacles"
    cached = getattr(ctx, attr, None)
    if cached is None:
        from scipy.spatial import cKDTree
        leaves_W = (np.vstack([ctx.leaf_W, ctx.other_leaves_W]) if held
                    else ctx.other_leaves_W)
        cached = ((cKDTree(leaves_W), (leaves_W.min(0), leaves_W.max(0))) if len(leaves_W)
                  else (None, None))
        setattr(ctx, attr, cached)
    return cached


def _TouchesLeaf(ctx: PlanningContext, margin: float, pts, held: bool = True) -> bool:
    """Whether the robot's surface samples ``pts`` come within ``margin``
    of an observed leaf (``_LeafObstacles``: every leaf, or with ``held``
    False the leaves not held); only samples near the leaves' box are
    queried."""
    tree, box = _LeafObstacles(ctx, held)
    if tree is None:
        return False
    near = NearBox(pts, box[0] - margin, box[1] + margin)
    return bool(len(near)) and tree.query(near)[0].min() < margin


def _OtherLeafReason(ctx: PlanningContext, cfg: PlannerConfig, pts) -> str:
    """'' or why the robot's surface samples ``pts`` (at a moved pose, the
    gripper closed) come within ``planner.collision_margin`` of a leaf that
    is not the one held (``ctx.other_leaves_W``): the arm would push a
    neighbouring leaf along the motion and drag it on the way back."""
    return ("robot-leaf (another leaf)"
            if _TouchesLeaf(ctx, cfg.collision_margin, pts, held=False) else "")


class _ApproachChecks:
    """Robot checks along an approach with the pads ``half_open`` (m) apart:
    fruit, branch and every observed leaf keep the margin from the robot
    (in the final approach the leaf must therefore pass between the open
    pads), and links three or more joints apart keep ``SELF_MARGIN`` (the
    approach's joint moves are fast and sampled). ``Pose(segment, q)`` is
    ``PlanApproach``'s check: "grasp" poses are the final approach, the
    others lie on the way to the pre-grasp; ``FreeMove`` samples the joint
    move from the current joints to the via point. Results are kept by
    joint vector and opening in ``memo`` (a ready pose closer to the
    pre-grasp repeats the approach's first poses)."""

    def __init__(self, ctx: PlanningContext, cfg: PlannerConfig, half_open: float,
                 memo: dict | None = None):
        self.ctx, self.cfg, self.half_open = ctx, cfg, float(half_open)
        self.memo = {} if memo is None else memo

    def _Reason(self, q: np.ndarray) -> str:
        """'' or the robot's reason at ``q`` without where: '...', or
        'robot-leaf'."""
        key = (np.asarray(q, float).tobytes(), self.half_open)
        if key in self.memo:
            return self.memo[key]
        robot, cfg = self.ctx.robot, self.cfg
        pts = robot.SurfacePointsByBody(q, self.half_open)
        why = _RobotPoseReason(robot, q, self.half_open, pts, self.ctx, cfg, SELF_MARGIN)
        if not why and _TouchesLeaf(self.ctx, cfg.collision_margin, pts):
            why = "robot-leaf"
        self.memo[key] = why
        return why

    def Pose(self, segment: str, q: np.ndarray) -> str:
        why = self._Reason(q)
        if not why:
            return ""
        if segment == "grasp":
            return why + (" during the approach (leaf not between the pads)"
                          if why == "robot-leaf" else " during the approach")
        return why + " on the way to the pre-grasp"

    def FreeMove(self, via: np.ndarray) -> str:
        q0 = self.ctx.q_current
        fractions = FreeMoveFractions(self.ctx.robot, q0, via, self.half_open)
        for f in fractions[::-1]:      # (the via point itself is checked)
            why = self.Pose("staging", q0 + f * (via - q0))
            if why:
                return why
        return ""


FREE_MOVE_STEP = 0.01    # m: the largest move of the robot between two checked poses


def FreeMoveFractions(robot, q0: np.ndarray, q1: np.ndarray, half_open: float,
                      step: float = FREE_MOVE_STEP, max_samples: int = 400) -> np.ndarray:
    """Fractions in (0, 1) of the joint move q0 -> q1 at which to check the
    robot so that no point of its geometries' boxes moves more than
    ``step`` (m) between two consecutive checks (a rigid motion moves a
    box's points at most as far as its farthest corner; the joint line is
    refined until the corners keep the step). Eight evenly spaced samples
    let the wrist skip 10 cm past a neighbouring leaf on a long move (the
    retreat's last move brushed one at 1.3 m/s in ``three_fruits_default``)."""
    q0, q1 = np.asarray(q0, float), np.asarray(q1, float)
    n = 8
    while True:
        f = np.linspace(0.0, 1.0, n)
        C = np.stack([robot.SurfacePointsByBody(q0 + x * (q1 - q0), half_open).corners
                      for x in f])
        moved = float(np.linalg.norm(np.diff(C, axis=0), axis=-1).max())
        if moved <= step or n >= max_samples:
            return f[1:-1]
        n = min(max_samples, int(np.ceil((n - 1) * moved / step)) + 1)


def NarrowOpening(leaf_W: np.ndarray, grasp, cfg: PlannerConfig) -> float:
    """The smallest pre-grasp opening (m) for ``grasp`` that keeps the
    collision margin plus 3 mm from the observed leaf on both pads: twice
    the leaf's local half-thickness along the closing direction (95th
    percentile of the leaf points within 1.5 cm of the grasp point, which
    includes the sensor noise) plus margins; never wider than
    ``pregrasp_opening``, never below 1.5 cm."""
    y = grasp.R_WG[:, 1]
    near = leaf_W[np.linalg.norm(leaf_W - grasp.p_WG, axis=1) < 0.015]
    half = float(np.percentile(np.abs((near - grasp.p_WG) @ y), 95)) if len(near) >= 5 else 0.005
    opening = 2.0 * (half + cfg.collision_margin + 0.003)
    return float(np.clip(opening, 0.015, cfg.pregrasp_opening))


def _Approach(ctx: PlanningContext, cfg: PlannerConfig, grasp, ready: float,
              memo: dict | None = None):
    """The approach to ``grasp`` with its ready pose ``ready`` (m) behind the
    pre-grasp (an ``ApproachPlan``), or why there is none: the configured
    opening first; if the open pads hit the fruit close behind the leaf (or
    the leaf), the narrowest opening that still lets the observed leaf pass
    between them. ``memo`` (a dict, one per grasp orientation) keeps IK
    solutions and pose checks for the next ready distance."""
    from lmap_drake.planning.motion import ApproachBlocked, MotionError, PlanApproach
    why = ""
    memo = memo if memo is not None else {}
    for opening in dict.fromkeys([cfg.pregrasp_opening,
                                  NarrowOpening(ctx.leaf_W, grasp, cfg)]):
        # each pose is checked as soon as it is solved, from the grasp
        # outward: a blocked approach stops before the rest of its IK
        checks = (_ApproachChecks(ctx, cfg, 0.5 * opening, memo.setdefault("checks", {}))
                  if np.isfinite(cfg.collision_margin) else None)
        try:
            approach = PlanApproach(ctx.robot,
                                    RigidTransform(RotationMatrix(grasp.R_WG), grasp.p_WG),
                                    ctx.q_current,
                                    grasp.R_WG[:, 1], cfg.pregrasp_distance, opening,
                                    ready_extra=ready,
                                    check=None if checks is None else checks.Pose,
                                    memo=memo.setdefault("ik", {}))
            why = "" if checks is None else checks.FreeMove(approach.via)
        except MotionError as err:
            return f"IK failed ({'staging' if err.staging else 'approach'}): {err}"
        except ApproachBlocked as err:
            why = str(err)
        if not why:
            return approach
        if not why.startswith(("robot-fruit", "robot-leaf")):
            break
    return why


def _IkAndRobotChecks(ctx: PlanningContext, grasp, cfg: PlannerConfig,
                      actions: list[Action]) -> list[Candidate]:
    """The approach (IK chain via, ready, pre-grasp, grasp; see
    ``planning.motion.PlanApproach``) with robot checks along it, then IK for
    each pulled pose (warm-started along each direction's distances) and
    robot-vs-fruit/branch checks there."""
    from lmap_drake.planning.motion import ApproachPlan
    cands = [Candidate(a, _DistanceId(a, cfg)) for a in actions]
    # If the arm cannot reach the ready pose or hits something on the way
    # to the pre-grasp, a ready pose closer to the pre-grasp
    # (``ready_distances``): on the far side of a plant the default one
    # can lie beyond the arm's reach.
    why = ""
    memo: dict = {}
    for ready in cfg.ready_distances:
        got = _Approach(ctx, cfg, grasp, ready, memo)
        if isinstance(got, ApproachPlan):
            approach, why = got, ""
            break
        why = got
        if not why.startswith("IK failed (staging)") and "on the way to the pre-grasp" not in why:
            break
    if why:
        for c in cands:
            c.reason = why
        return cands
    for c in cands:
        c.approach = approach
        c.q_pregrasp, c.q_grasp = approach.to_pregrasp[-1], approach.to_grasp[-1]
    return _MotionChecks(ctx, cfg, cands, approach.to_grasp[-1])


def _MotionChecks(ctx: PlanningContext, cfg: PlannerConfig, cands: list[Candidate],
                  q_grasp: np.ndarray) -> list[Candidate]:
    """IK for each action's end pose (and an arc's midway pose), warm-started
    along each direction's distances from ``q_grasp`` (the joints holding
    the grasp), and robot-vs-fruit/branch checks there (gripper closed), and
    robot vs the leaves not held (``_OtherLeafReason``)."""
    robot = ctx.robot
    seeds: dict[int, np.ndarray] = {}
    solved: dict[tuple, tuple] = {}
    for c in sorted(cands, key=lambda c: (c.action.direction_id, c.action.distance)):
        c.q_grasp = q_grasp if c.q_grasp is None else c.q_grasp
        seed = seeds.get(c.action.direction_id, q_grasp)
        a = c.action
        # An arc also turns the wrist: its midway pose is checked too (the
        # arcs of one axis come in increasing angles, so consecutive ends
        # and midpoints sample the whole sweep).
        # (Arc poses already solved for this axis, e.g. the 30-degree end as
        # the 60-degree arc's midway pose, are reused.)
        poses = [(a.angle, a.p_WG + a.dp_W, a.R_WG_end)]
        if a.family != "pull":
            mid = dc.replace(a, angle=0.5 * a.angle, dp_W=None)
            poses.insert(0, (mid.angle, mid.p_WG + mid.dp_W, mid.R_WG_end))
        why = ""
        for angle, p, R_end in poses:
            key = (a.direction_id, round(angle, 9)) if a.family != "pull" else None
            if key in solved:
                r, pose_why = solved[key]
            else:
                r = robot.Ik(RigidTransform(RotationMatrix(R_end), p), seed, 0.0)
                pose_why = ""
                if r.success:
                    pts = robot.SurfacePointsByBody(r.q, 0.0)
                    pose_why = (_RobotPoseReason(robot, r.q, 0.0, pts, ctx, cfg)
                                or _OtherLeafReason(ctx, cfg, pts))
                if key is not None:
                    solved[key] = (r, pose_why)
            if not r.success:
                why = f"IK failed ({'pulled pose' if a.family == 'pull' else 'along the ' + a.family})"
                break
            seed = r.q
            why = why or pose_why
        if why.startswith("IK failed"):
            c.reason = why
            continue
        seeds[c.action.direction_id] = r.q
        c.q_pulled = r.q
        if why:
            c.reason = why
    return cands


def _DistanceId(a: Action, cfg: PlannerConfig) -> int:
    """Index of the action's distance in ``planner.distances`` (pulls) or
    of its angle in ``planner.arc_angles_deg`` (arcs)."""
    if a.family != "pull":
        deg = np.asarray(cfg.arc_angles_deg if a.family == "arc" else cfg.twist_angles_deg,
                         float)
        return int(np.argmin(np.abs(deg - np.rad2deg(abs(a.angle)))))
    return int(round(a.distance / 0.02)) - 1


def HingeRotationDeg(hinge_W, p_from_W, p_to_W) -> float:
    """Angle (deg) by which the grasp point turned about the hinge, from
    ``p_from_W`` to ``p_to_W``; NaN without a hinge."""
    if hinge_W is None:
        return float("nan")
    u, v = np.asarray(p_from_W) - hinge_W, np.asarray(p_to_W) - hinge_W
    c = u @ v / max(np.linalg.norm(u) * np.linalg.norm(v), 1e-12)
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def EquivalentTurnDeg(bend_deg: float, twist_rad: float, torsion_ratio: float) -> float:
    """The petiole's load as one turn (deg): sqrt(bend^2 + ratio twist^2),
    ``bend_deg`` the turn of the grasp point about the hinge, ``twist_rad``
    the leaf's twist about the hinge-grasp line and ``ratio`` the petiole's
    torsional to bending stiffness (the energies k_b bend^2 + k_t twist^2
    written as one bend). NaN without a hinge."""
    if not np.isfinite(bend_deg):
        return bend_deg
    return float(np.hypot(bend_deg, np.sqrt(max(torsion_ratio, 0.0)) * np.degrees(twist_rad)))


def PetioleBendingEnergy(hinge_deg: float, weight: float) -> float:
    """Per leaf node (m^2): ``weight`` * theta^2 (theta in rad), the petiole
    bending where it joins the branch when the leaf turns by theta about
    it. The deformation graph ties the leaf to the branch by a chain of
    nodes whose bending ARAP barely resists, so without this term a
    60-degree swing of the leaf costs ~50x less than an 8 cm pull, while
    the FEM petiole carries 40-60 % of that pull's force (measured with
    ``scripts/eval_hazard_prediction.py``). 0 without a hinge."""
    if not np.isfinite(hinge_deg):
        return 0.0
    return float(weight * np.radians(hinge_deg) ** 2)


def EstimateHinge(leaf_W: np.ndarray, branch_W: np.ndarray,
                  dcfg: DeformationConfig | None = None) -> np.ndarray | None:
    """The point the leaf swings about: the branch point nearest to the
    observed leaf's main part (``MainLeafComponent``; where its petiole
    joins the branch). None without branch or leaf points."""
    from scipy.spatial import cKDTree
    if len(branch_W) == 0 or len(leaf_W) == 0:
        return None
    leaf_W = np.asarray(leaf_W, float)
    leaf_W = leaf_W[MainLeafComponent(leaf_W, dcfg or DeformationConfig())]
    d, j = cKDTree(branch_W).query(leaf_W)
    return np.asarray(branch_W[j[int(np.argmin(d))]], float)


def _Normalize(x: np.ndarray) -> np.ndarray:
    lo, hi = np.nanmin(x), np.nanmax(x)
    return np.zeros_like(x) if hi - lo < 1e-12 else (x - lo) / (hi - lo)


def SelectAction(feasible: list[Candidate], energy_weight: float) -> Candidate:
    """Paper Eq. (7): argmax of N_vis - lambda * E, both min-max normalised
    over the feasible actions; sets each candidate's ``score``."""
    if not feasible:
        raise PlanningError("no feasible action to select from")
    nv = _Normalize(np.array([c.n_vis for c in feasible], float))
    ne = _Normalize(np.array([c.energy for c in feasible], float))
    for c, a, b in zip(feasible, nv, ne):
        c.score = float(a - energy_weight * b)
    return max(feasible, key=lambda c: c.score)


def AttachLeaf(scene: SceneEstimate, dcfg: DeformationConfig) -> tuple[SceneEstimate, str]:
    """The scene with ``leaf_attachment_W`` set: if the observed leaf's
    main part (``MainLeafComponent``: the blade, not specks labelled leaf
    elsewhere) has no edge to the branch in the deformation graph (no leaf
    voxel node within the leaf-branch edge radius of a branch voxel node:
    its petiole unseen), a virtual petiole (points one voxel apart from its
    nearest point to the nearest branch point) ties it to the branch.
    Returns the scene and a message ('' if nothing was added).

    The test is the graph's own, on voxel nodes: on points (nearest point
    under the radius less a voxel) a blade 1.2 cm from the stem passed as
    attached while its nodes were not, and every grasp of
    ``small_leaf_thin_branch_round_yellow_heavy`` then had "no path to a
    fixed (branch) node". The petiole starts at the blade's voxel node
    nearest the branch and its points lie a third of a voxel apart: started
    at the nearest point, a voxel beyond it, with points a voxel apart, its
    first node could lie beyond the leaf-leaf edge radius from the blade's
    (voxel nodes are centroids); in that scene the blade hung from nothing,
    and so it did in 15 of 400 random placements of a test blade 2-5 cm
    from its stem. A node is a centroid, so the chain could still break
    (1 of 400): the graph of blade + petiole is now checked
    (``_HangsFromBranch``) and, where the blade hangs from nothing, the
    petiole gets four parallel lines a third (then half) a voxel to its
    sides: 0 of 1400 random placements left unattached, 3 thickened."""
    from scipy.spatial import cKDTree
    leaf = np.asarray(scene.semantic.leaf_points_W, float).reshape(-1, 3)
    leaf = leaf[np.isfinite(leaf).all(axis=1)]
    leaf = leaf[MainLeafComponent(leaf, dcfg)]
    branch = [np.asarray(scene.semantic.branch_points_W, float).reshape(-1, 3)]
    if scene.branch is not None:
        branch.append(scene.branch.samples_W)
    branch = np.vstack(branch)
    branch = branch[np.isfinite(branch).all(axis=1)]
    if len(branch) == 0 or len(leaf) == 0:
        return scene, ""
    leaf_nodes, _ = Voxelize(leaf, dcfg.voxel_size)
    branch_nodes, _ = Voxelize(branch, dcfg.voxel_size)
    if cKDTree(branch_nodes).query(leaf_nodes)[0].min() <= dcfg.leaf_branch_edge_radius:
        return scene, ""
    d, j = cKDTree(branch).query(leaf_nodes)
    i = int(np.argmin(d))
    a, b = leaf_nodes[i], branch[j[i]]
    # from the blade's node nearest the branch to one step short of the
    # branch, a third of a voxel apart (see the docstring)
    n = int(np.ceil(d[i] / (dcfg.voxel_size / 3.0)))
    line = a + np.outer(np.linspace(0, 1, n + 1)[:-1], b - a)
    # A chain of centroids can still break (see the docstring): checked on
    # the graph itself, and where it breaks the petiole is thickened by
    # parallel lines a third, then half a voxel to its sides.
    u = (b - a) / max(np.linalg.norm(b - a), 1e-12)
    e1 = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    petiole = line
    for r in (1 / 3, 1 / 2):
        if _HangsFromBranch(leaf, petiole, branch, dcfg):
            break
        petiole = np.vstack([line] + [line + r * dcfg.voxel_size * sgn * e
                                      for e in (e1, e2) for sgn in (1, -1)])
    return (dc.replace(scene, leaf_attachment_W=petiole),
            f"leaf seen {d[i] * 100:.1f} cm from the branch (petiole unseen): "
            f"attached by a virtual petiole of {len(petiole)} points")


def _HangsFromBranch(blade_W: np.ndarray, petiole_W: np.ndarray, branch_W: np.ndarray,
                     dcfg: DeformationConfig) -> bool:
    """Whether the deformation graph of blade + petiole (W, m) ties the
    blade's largest component to a fixed (branch) node."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    try:
        g = BuildLeafGraph(np.vstack([blade_W, petiole_W]), branch_W, dcfg)
    except DeformationError:
        return False
    n = len(g.nodes_W)
    adj = coo_matrix((np.ones(len(g.edges)), (g.edges[:, 0], g.edges[:, 1])), shape=(n, n))
    _, label = connected_components(adj, directed=False)
    blade = np.bincount(label[:g.num_leaf]).argmax()
    return bool(blade in set(label[g.num_leaf:]))


@dc.dataclass
class CandidateSet:
    """Stage 1 output: candidates with IK and robot checks done, the
    visibility model and the initial/maximum visibility, or an early
    status ('no_action_needed', 'no_feasible_action', 'no_fruit')."""
    status: str
    scene: SceneEstimate
    candidates: list[Candidate] = dc.field(default_factory=list)
    dropped_grasps: list[dict] = dc.field(default_factory=list)
    visibility: VisibilityModel | None = None
    seen_init_mask: np.ndarray | None = None
    timings: dict = dc.field(default_factory=dict)
    message: str = ""
    hinge_W: np.ndarray | None = None   # the arcs' pivot (estimated petiole attachment)

    def LiveActions(self) -> list[Action]:
        """Actions still feasible after IK and robot checks (for deformation)."""
        return [c.action for c in self.candidates if c.feasible]


def GenerateCandidates(ctx: PlanningContext, cfg: PlannerConfig, dcfg: DeformationConfig,
                       progress=None) -> CandidateSet:
    """Paper Sec. III-C-1 (generation and collision checking) plus the
    initial and maximum visibility. Never raises on a bad scene."""
    progress = progress or (lambda m: None)
    timings = {"generation_collision_s": 0.0, "visibility_s": 0.0}
    if ctx.scene.fruit is None:
        return CandidateSet("no_fruit", ctx.scene, timings=timings,
                            message="no fruit estimate: nothing to reveal")
    if not np.all(np.isfinite(ctx.scene.fruit.vertices_W)) or len(ctx.scene.fruit.faces) == 0:
        return CandidateSet("no_fruit", ctx.scene, timings=timings,
                            message="the fruit estimate is empty or not finite")
    t0 = time.perf_counter()
    vis = VisibilityModel(ctx.X_WC, FruitSurfaceSamples(ctx.scene.fruit), cfg.visibility_voxel,
                          ctx.image_tan)
    seen_init = vis.Seen(np.vstack([ctx.leaf_W, ctx.occluders_W]))
    if ctx.seen_before_W is not None:
        seen_init = seen_init | vis.Observed(ctx.seen_before_W)
    timings["visibility_s"] += time.perf_counter() - t0
    out = CandidateSet("ok", ctx.scene, visibility=vis, seen_init_mask=seen_init,
                       timings=timings)
    n_init, n_max = int(seen_init.sum()), int(vis.max_seen.sum())
    if n_max == 0:
        out.status = "no_fruit"
        out.message = ("the fruit estimate is outside camera0's view: no part of it could "
                       "be seen, so no action can reveal it")
        return out
    if n_init >= cfg.early_stop_fraction * n_max:
        out.status, out.message = "no_action_needed", f"fruit already {n_init / n_max:.0%} visible"
        return out
    if len(ctx.leaf_W) < 10:
        out.status, out.message = "no_feasible_action", "no leaf points to grasp"
        return out
    t0 = time.perf_counter()
    try:
        grasps, out.dropped_grasps = GraspCandidates(
            ctx.leaf_W, ctx.branch_all_W, ctx.p_WC, cfg.num_grasps, cfg.grasp_inset,
            cfg.min_branch_distance)
    except (PlanningError, ValueError) as err:
        out.status, out.message = "no_feasible_action", f"no grasp candidates: {err}"
        return out
    all_dirs = PullDirections()[:cfg.num_directions]
    pivot = EstimateHinge(ctx.leaf_W, ctx.branch_all_W, dcfg)
    out.hinge_W = pivot
    angles = np.deg2rad(np.asarray(cfg.arc_angles_deg, float))
    failed = []
    for g in grasps:
        actions = GraspActions(ctx, cfg, g, pivot, angles, all_dirs)
        cands = _IkAndRobotChecks(ctx, g, cfg, actions)
        if all(c.approach is None for c in cands):
            failed.append((g, actions))
        out.candidates += cands
    if len({c.action.grasp_id for c in out.candidates if c.feasible}) < cfg.min_usable_grasps:
        _SecondChanceGrasps(ctx, cfg, out, failed, grasps, pivot, angles, all_dirs)
    timings["generation_collision_s"] += time.perf_counter() - t0
    out.scene, msg = AttachLeaf(ctx.scene, dcfg)
    out.message = msg
    progress(f"{len(out.candidates)} candidates from {len(grasps)} grasps, "
             f"{len(out.LiveActions())} pass IK and robot checks")
    return out


# Second-chance grasp orientations: the approach turned by these angles
# (deg) about the pads' closing axis, i.e. within the blade's plane, still
# crossing the leaf's edge; each also turned 180 deg about the approach axis.
# 70 deg comes in nearly from the leaf's side: for leaves on the far side of
# a plant that point away from the robot, whose approach from beyond the
# edge the arm cannot reach (four_fruits: a fruit 0.44 -> 0.98 visible).
APPROACH_TILTS_DEG = (0.0, 35.0, -35.0, 70.0, -70.0)


def GraspAlternatives(R_WG: np.ndarray) -> list[np.ndarray]:
    """Other gripper orientations for a grasp whose own approach failed, pads
    still closing across the leaf (G's y axis along the leaf normal): the
    2F-85 turned 180 deg about its approach axis (it is symmetric; the wrist
    then sits the other way), and the approach tilted by
    ``APPROACH_TILTS_DEG`` in the blade's plane (about G's y axis)."""
    from lmap_drake.deformation.action import AxisAngleMatrix
    R_WG = np.asarray(R_WG, float)
    out = []
    for tilt in APPROACH_TILTS_DEG:
        R = R_WG @ AxisAngleMatrix([0.0, 1.0, 0.0], np.deg2rad(tilt))
        out += [R, R @ np.diag([-1.0, -1.0, 1.0])]
    return out[1:]                      # not the orientation already tried


def _AlternativeLabels() -> list[tuple]:
    """(tilt deg, turned 180 deg) of each ``GraspAlternatives`` rotation."""
    return [(float(t), turned) for t in APPROACH_TILTS_DEG for turned in (False, True)][1:]


def _SecondChanceGrasps(ctx: PlanningContext, cfg: PlannerConfig, out: CandidateSet,
                        failed: list, grasps: list, pivot, angles, all_dirs) -> None:
    """Fewer than ``planner.min_usable_grasps`` grasps gave a feasible
    action (a small leaf near the branch, a leaf edge the arm reaches
    awkwardly): the grasps whose approach failed are retried with the other
    orientations (``GraspAlternatives``), and grasps dropped for lying
    within ``min_branch_distance`` of the branch, but at least half of it
    away, are tried too (the robot-branch checks still apply). A grasp's
    first orientation whose approach passes replaces its candidates.
    Still short, the grasp set is made again deeper inside the blade (each
    of ``planner.deeper_grasp_insets`` in turn, ids ``DEEPER_GRASP_IDS`` x
    (k + 1) + i), each grasp in its first orientation whose approach passes
    (``_DeeperGrasps``)."""
    tried = {g.grasp_id for g in grasps}
    near, _ = GraspCandidates(ctx.leaf_W, ctx.branch_all_W, ctx.p_WC, cfg.num_grasps,
                              cfg.grasp_inset, 0.5 * cfg.min_branch_distance)
    extra = []
    for g in near:
        if g.grasp_id in tried:
            continue
        actions = GraspActions(ctx, cfg, g, pivot, angles, all_dirs)
        cands = _IkAndRobotChecks(ctx, g, cfg, actions)
        out.candidates += cands
        out.dropped_grasps = [d for d in out.dropped_grasps if d["grasp_id"] != g.grasp_id]
        if all(c.approach is None for c in cands):
            extra.append((g, actions))
    for g, actions in failed + extra:
        cands = _FirstApproach(ctx, cfg, g, actions, GraspAlternatives(g.R_WG),
                               _AlternativeLabels())
        if cands:
            out.candidates = [c for c in out.candidates
                              if c.action.grasp_id != g.grasp_id] + cands
    _DeeperGrasps(ctx, cfg, out, pivot, angles, all_dirs)


def _FirstApproach(ctx: PlanningContext, cfg: PlannerConfig, g, actions: list[Action],
                   rotations: list[np.ndarray], labels: list) -> list[Candidate] | None:
    """The candidates of grasp ``g``'s ``actions`` turned to the first of
    ``rotations`` (R_WG; ``labels``: their record orientations) whose
    approach passes, or None when none does."""
    from lmap_drake.planning.candidates import Grasp
    for R, label in zip(rotations, labels):
        cands = _IkAndRobotChecks(ctx, Grasp(g.p_WG, R, g.grasp_id), cfg,
                                  [dc.replace(a, R_WG=R) for a in actions])
        if any(c.approach is not None for c in cands):
            for c in cands:
                c.orientation = label
            return cands
    return None


# Grasp ids of the deeper grasp sets: DEEPER_GRASP_IDS x (k + 1) + i for the
# i-th grasp of the k-th of ``planner.deeper_grasp_insets``.
DEEPER_GRASP_IDS = 100


def _DeeperGrasps(ctx: PlanningContext, cfg: PlannerConfig, out: CandidateSet,
                  pivot, angles, all_dirs) -> None:
    """While fewer than ``planner.min_usable_grasps`` grasps give a feasible
    action, the grasp set again at each of ``planner.deeper_grasp_insets``
    (m inside the leaf's outline instead of ``grasp_inset``): on a crowded
    plant every grasp 1 cm inside the rim can fail a robot check by a few
    millimetres (``four_fruits``: 15 grasps 2-3 mm from a run where 2 had
    passed, none passing), and one a centimetre deeper comes in past what
    the fingers met. Each grasp keeps its first orientation
    (``GraspAlternatives``, the given one first) whose approach passes;
    grasps whose every orientation fails are not added (the rejection
    counts stay those of the rim's grasps)."""
    from lmap_drake.planning.candidates import Grasp
    for k, inset in enumerate(cfg.deeper_grasp_insets):
        if len({c.action.grasp_id for c in out.candidates if c.feasible}) >= cfg.min_usable_grasps:
            return
        try:
            deep, _ = GraspCandidates(ctx.leaf_W, ctx.branch_all_W, ctx.p_WC, cfg.num_grasps,
                                      float(inset), cfg.min_branch_distance)
        except (PlanningError, ValueError):
            continue
        for g in deep:
            g = Grasp(g.p_WG, g.R_WG, DEEPER_GRASP_IDS * (k + 1) + g.grasp_id)
            actions = GraspActions(ctx, cfg, g, pivot, angles, all_dirs)
            cands = _FirstApproach(ctx, cfg, g, actions, [g.R_WG] + GraspAlternatives(g.R_WG),
                                   [None] + _AlternativeLabels())
            out.candidates += cands or []


# The grasp-attachment lever (m) at which ``planner.max_pull_distance`` holds.
PULL_LEVER_REFERENCE = 0.10


def MaxPullDistance(cfg: PlannerConfig, p_WG: np.ndarray,
                    hinge_W: np.ndarray | None) -> float:
    """The longest straight pull (m) allowed from grasp ``p_WG``:
    ``planner.max_pull_distance`` times (L / ``PULL_LEVER_REFERENCE``)^2, L
    the grasp's distance to the estimated attachment ``hinge_W`` (the leaf
    as a beam clamped at its petiole: a grasp moved by d bends the petiole
    with a moment that grows as d / L^2). Without a hinge the cap is not
    scaled; inf when ``max_pull_distance`` is 0 (no cap)."""
    cap = cfg.max_pull_distance
    if cap <= 0:
        return float("inf")
    if hinge_W is not None:
        lever = float(np.linalg.norm(np.asarray(p_WG, float) - np.asarray(hinge_W, float)))
        cap *= (lever / PULL_LEVER_REFERENCE) ** 2
    return cap


# The widest arc (deg) allowed at ``planner.arc_lever_reference``.
ARC_REFERENCE_DEG = 45.0


def MaxArcAngle(cfg: PlannerConfig, p_WG: np.ndarray, hinge_W: np.ndarray | None) -> float:
    """The widest arc (deg) about the estimated attachment ``hinge_W``
    allowed from grasp ``p_WG``: ``ARC_REFERENCE_DEG`` times L /
    ``planner.arc_lever_reference``, L the grasp's distance to it, at most
    ``ARC_REFERENCE_DEG``. Turning the blade by a given angle takes a
    moment at the petiole, and the grasp supplies it with a force that grows
    as the lever shortens. inf when ``arc_lever_reference`` is 0 or there
    is no hinge (no cap)."""
    ref = cfg.arc_lever_reference
    if ref <= 0 or hinge_W is None:
        return float("inf")
    lever = float(np.linalg.norm(np.asarray(p_WG, float) - np.asarray(hinge_W, float)))
    return ARC_REFERENCE_DEG * min(1.0, lever / ref)


def PullDistances(cfg: PlannerConfig, p_WG: np.ndarray, hinge_W: np.ndarray | None
                  ) -> list[float]:
    """The straight pulls' distances (m) from grasp ``p_WG``:
    ``planner.distances`` and, when it falls between two of them and at
    least 5 mm from each, the longest pull the grasp's lever allows
    (``MaxPullDistance``, floored to the millimetre). Without it a grasp
    whose cap is 4.7 cm stopped at the 4 cm pull: in ``four_fruits`` 0.71 of
    its fruit predicted, 0.91 at the 6 cm the cap refused."""
    ds = sorted(float(d) for d in cfg.distances)
    cap = MaxPullDistance(cfg, p_WG, hinge_W)
    if ds and np.isfinite(cap):
        cap = float(np.floor(cap * 1000.0)) / 1000.0
        if ds[0] < cap < ds[-1] and min(abs(cap - d) for d in ds) >= 0.005:
            ds = sorted(ds + [cap])
    return ds


def GraspActions(ctx: PlanningContext, cfg: PlannerConfig, g, pivot, angles, all_dirs
                  ) -> list[Action]:
    """Every configured motion (pulls, arcs, twists) from grasp ``g``."""
    actions = []
    if "pull" in cfg.action_families:
        dirs, dir_ids = DirectionsForGrasp(g.p_WG, ctx.branch_all_W,
                                           cfg.max_branch_angle_deg, all_dirs)
        actions += [Action(g.p_WG, g.R_WG, s * u, grasp_id=g.grasp_id, direction_id=int(j))
                    for u, j in zip(dirs, dir_ids) for s in PullDistances(cfg, g.p_WG, pivot)]
    if pivot is not None and np.linalg.norm(g.p_WG - pivot) > 0.02:
        if "arc" in cfg.action_families:
            actions += MakeArcActions(g.p_WG, g.R_WG, pivot,
                                      HingeAxes(g.p_WG, pivot, cfg.num_arc_axes), angles,
                                      grasp_id=g.grasp_id)
        if "twist" in cfg.action_families:
            actions += MakeTwistActions(g.p_WG, g.R_WG, pivot,
                                        np.deg2rad(np.asarray(cfg.twist_angles_deg, float)),
                                        grasp_id=g.grasp_id)
    return actions


def _ForcedKey(force_action) -> tuple[int, int, float]:
    return int(force_action[0]), int(force_action[1]), float(force_action[2])


def ForcedCandidate(cands: list[Candidate], force_action) -> Candidate | None:
    """The candidate named by ``planner.force_action`` ([grasp_id,
    direction_id, distance m]), or None (off, or no such candidate)."""
    if not force_action:
        return None
    g, d, dist = _ForcedKey(force_action)
    for c in cands:
        a = c.action
        if a.grasp_id == g and a.direction_id == d and abs(a.distance - dist) < 6e-5:
            return c
    return None


def _ChooseForced(result: PlanResult, forced: Candidate | None, force_action) -> PlanResult:
    """``result`` with the forced candidate chosen, or status
    'no_feasible_action' if it does not exist or failed the robot checks."""
    g, d, dist = _ForcedKey(force_action)
    name = f"forced action (grasp {g}, direction {d}, {dist * 100:g} cm)"
    if forced is None:
        result.status = "no_feasible_action"
        result.message = f"{name} is not among the {len(result.candidates)} candidates"
    elif forced.q_pulled is None or forced.deformed_leaf_W is None:
        result.status = "no_feasible_action"
        result.message = f"{name} failed the robot checks: {forced.reason}"
    else:
        result.chosen = forced
        result.message = f"{name}: {forced.reason or 'passes every check'}"
    return result


def CompoundEnergyPerNode(before: float, after: float) -> float:
    """An upper bound of the ARAP energy per node of two motions executed in
    turn, ``before`` (from the rest shape) and ``after`` (predicted from the
    shape ``before`` left): sqrt(E) is a norm of the deformation for small
    strains, so sqrt(E_total) <= sqrt(E_before) + sqrt(E_after). Their sum
    assumes the two deformations independent; a motion that keeps loading
    the leaf the same way compounds (a pull, then an arc or a twist: 14.6
    and 15.4 N on the petiole in two multi-fruit episodes whose summed
    energies per node, 4.4 and 3.6e-7, were under the cap)."""
    before, after = max(0.0, float(before)), max(0.0, float(after))
    return float((np.sqrt(before) + np.sqrt(after)) ** 2)


def SelectFromPredictions(ctx: PlanningContext, cset: CandidateSet, predictions: list,
                          cfg: PlannerConfig, method: str = "lmap",
                          energy_offset_per_node: float = 0.0,
                          hinge_reference_W: np.ndarray | None = None,
                          min_gain: float = 0.0, twist_offset_rad: float = 0.0
                          ) -> PlanResult:
    """Paper Sec. III-C-2/3: leaf-fruit checks, visibility with early stop
    along the distances, and the score. ``predictions`` are aligned with
    ``cset.LiveActions()`` (``PredictedDeformation``: ``energy``,
    ``leaf_points_W`` dense, the observed leaf first)."""
    # Work on copies: ``cset`` may be a cached Drake output (never mutate it).
    cands = [dc.replace(c) for c in cset.candidates]
    result = PlanResult(cset.status, method, candidates=cands,
                        dropped_grasps=cset.dropped_grasps, timings=dict(cset.timings),
                        message=cset.message, hinge_W=cset.hinge_W)
    if cset.visibility is not None:
        result.seen_init = int(cset.seen_init_mask.sum())
        result.seen_max = int(cset.visibility.max_seen.sum())
    if cset.status != "ok":
        return result
    live = [c for c in cands if c.feasible]
    if len(predictions) != len(live):
        raise PlanningError(f"{len(predictions)} predictions for {len(live)} live actions")
    n_leaf = len(ctx.leaf_W)
    # a re-plan from the held leaf (``hinge_reference_W``, the first grasp)
    # also keeps its own limit on the turn; the reason names the binding one
    limits = [("max_hinge_deg", cfg.max_hinge_deg)]
    if hinge_reference_W is not None:
        limits.append(("max_replan_turn_deg", cfg.max_replan_turn_deg))
    max_turn_key, max_turn = min(limits, key=lambda kv: kv[1])
    for c, p in zip(live, predictions):
        if isinstance(p, UnmodelledGrasp):
            c.reason = f"deformation model: {p.message}"
            continue
        c.arap_energy = float(p.energy)
        c.num_leaf_nodes = int(np.count_nonzero(np.asarray(p.node_kind) == FREE))
        ref = c.action.p_WG if hinge_reference_W is None else hinge_reference_W
        c.hinge_deg = EquivalentTurnDeg(
            HingeRotationDeg(cset.hinge_W, ref, c.action.p_WG + c.action.dp_W),
            twist_offset_rad + (abs(c.action.angle) if c.action.family == "twist" else 0.0),
            cfg.petiole_torsion_ratio)
        c.energy = c.arap_energy + c.num_leaf_nodes * PetioleBendingEnergy(
            c.hinge_deg, cfg.hinge_bending_weight)
        if np.isfinite(c.hinge_deg) and c.hinge_deg > max_turn:
            c.reason = (f"turns the leaf {c.hinge_deg:.0f} deg about its petiole attachment "
                        f"({max_turn_key} {max_turn:g})")
        elif cset.hinge_W is not None and cfg.max_tether_elongation > 0:
            # the petiole is stiff along its axis: pulling the grasp away
            # from the attachment loads it, whatever the blade does
            tether = TetherElongation(ref, c.action.p_WG + c.action.dp_W, cset.hinge_W)
            if tether > cfg.max_tether_elongation:
                c.reason = (f"pulls the grasp {tether * 100:.1f} cm farther from the petiole "
                            f"attachment (max_tether_elongation {cfg.max_tether_elongation:g} m)")
        c.deformed_leaf_W = np.asarray(p.leaf_points_W)[:n_leaf]
    vis, seen_init, n_max = cset.visibility, cset.seen_init_mask, result.seen_max
    t0 = time.perf_counter()
    by_dir: dict[tuple, list[Candidate]] = {}
    for c in cands:
        by_dir.setdefault((c.action.grasp_id, c.action.direction_id), []).append(c)
    forced = ForcedCandidate(cands, cfg.force_action)
    rest_sdf = None       # the fruit SDF at the observed leaf, evaluated once
    rest_branch = None    # the branch distance there, likewise
    static_zbuf = None
    for dir_cands in by_dir.values():
        reached = False
        for c in sorted(dir_cands, key=lambda c: c.action.distance):
            if reached and c.feasible:
                c.reason = "beyond the distance that reaches 95 % visibility"
            # A forced action is scored whatever the planner thinks of it.
            is_forced = c is forced and c.deformed_leaf_W is not None
            if not (c.feasible or is_forced):
                continue
            if rest_sdf is None and ctx.fruit_sdf is not None:
                rest_sdf = np.asarray(ctx.fruit_sdf(ctx.leaf_W), float)
            why = LeafCollisionReason(ctx.leaf_W, c.deformed_leaf_W, ctx.fruit_sdf,
                                      cfg.collision_margin, ctx.fruit_box, rest_sdf)
            if not why and cfg.check_leaf_branch and ctx.branch_distance is not None:
                # the held leaf swung into a stem or shoot (the FEM leaf
                # then presses it, loading its own petiole); points resting
                # on a branch (the petiole's base) are not counted
                if rest_branch is None:
                    rest_branch = np.asarray(ctx.branch_distance(ctx.leaf_W), float)
                why = LeafCollisionReason(ctx.leaf_W, c.deformed_leaf_W, ctx.branch_distance,
                                          cfg.collision_margin, ctx.branch_box, rest_branch,
                                          what="branch", ignore_touching=True)
            if why:
                c.reason = c.reason or why
                if not is_forced:
                    continue
            if static_zbuf is None:     # these occlude the same for every action
                static_zbuf = vis.ZBuffer(ctx.occluders_W)
            seen = vis.Seen(np.vstack([c.deformed_leaf_W,
                                       ctx.robot.SurfacePoints(c.q_pulled)]), static_zbuf)
            c.seen = int(seen.sum())
            c.n_vis = CountNewlySeen(seen, seen_init)
            if c.seen >= cfg.early_stop_fraction * n_max:
                reached = True
    result.timings["visibility_s"] = result.timings.get("visibility_s", 0.0) + \
        time.perf_counter() - t0
    if min_gain > 0 and n_max:
        # (re-planning) a further motion must show clearly more of the
        # fruit than the leaf held where it is: the normalised score alone
        # would pick some action even if every one reveals less.
        for c in cands:
            if c.feasible and c.seen < result.seen_init + min_gain * n_max:
                c.reason = (f"predicted visibility {c.seen / n_max:.2f} not above the "
                            f"current {result.seen_init / n_max:.2f} + {min_gain:g}")
    feasible = [c for c in cands if c.feasible]
    if feasible:
        # The paper's score, normalised over every action that passed the
        # checks; the energy cap and the pull cap then filter (normalising
        # over the capped set instead would shift the lambda trade-off: a
        # veto should not re-rank what it leaves).
        SelectAction(feasible, cfg.energy_weight)
        for c in feasible:
            if c.action.family == "pull":
                longest = MaxPullDistance(cfg, c.action.p_WG, cset.hinge_W)
                if c.action.distance > longest + 1e-9:
                    c.reason = (f"a {c.action.distance * 100:.0f} cm straight pull from a grasp "
                                f"this near the attachment (at most {longest * 100:.1f} cm: "
                                f"max_pull_distance {cfg.max_pull_distance:g} m at a "
                                f"{PULL_LEVER_REFERENCE * 100:.0f} cm lever)")
            elif c.action.family == "arc":
                widest = MaxArcAngle(cfg, c.action.p_WG, cset.hinge_W)
                deg = float(np.degrees(abs(c.action.angle)))
                if deg > widest + 1e-6:
                    c.reason = (f"a {deg:.0f} deg arc from a grasp this near "
                                f"the attachment (at most {widest:.0f} deg: "
                                f"{ARC_REFERENCE_DEG:.0f} deg at arc_lever_reference "
                                f"{cfg.arc_lever_reference * 100:g} cm)")
        feasible = [c for c in feasible if c.feasible]
        cap = cfg.max_energy_per_node
        if cap > 0:
            for c in feasible:
                e = c.EnergyPerNode()
                if e is not None and energy_offset_per_node > 0:
                    arap = c.arap_energy / max(1, c.num_leaf_nodes)
                    e = CompoundEnergyPerNode(energy_offset_per_node, arap) + (e - arap)
                if e is not None and e > cap:
                    c.reason = (f"predicted energy per leaf node {e:.2e} m^2 above "
                                f"max_energy_per_node {cap:.2e} (damage risk)")
            feasible = [c for c in feasible if c.feasible]
    if cfg.force_action:
        return _ChooseForced(result, forced, cfg.force_action)
    if not feasible:
        result.status = "no_feasible_action"
        result.message = "no feasible action: " + NoActionReason(cands, cset.dropped_grasps,
                                                                 cfg)
        return result
    # The best action whose executed path (as the controller will run it)
    # passes; a failing one is rejected and the next best taken.
    while feasible:
        best = max(feasible, key=lambda c: c.score)
        why = _ActionPathReason(ctx, cfg, best)
        if not why:
            result.chosen = best
            return result
        best.reason = why
        feasible = [c for c in feasible if c.feasible]
    result.status = "no_feasible_action"
    result.message = "no feasible action: " + NoActionReason(cands, cset.dropped_grasps, cfg)
    return result


def _ActionPathReason(ctx: PlanningContext, cfg: PlannerConfig, c: Candidate) -> str:
    """'' or why candidate ``c``'s motion fails along the joint path the
    controller will execute (``PlanActionPath`` from its grasp joints,
    straightened near a wrist singularity, so it may differ from the end
    and midway poses the candidate checks solved on their own): no IK,
    self-collision, or a waypoint within the margins of a fruit, a branch
    or a leaf not held."""
    from lmap_drake.planning.motion import MotionError, PlanActionPath
    if c.q_grasp is None:
        return ""
    try:
        path = PlanActionPath(ctx.robot, c.action, c.q_grasp)
    except MotionError as err:
        return f"executed path: {' '.join(str(err).split())}"
    for q in path:
        pts = ctx.robot.SurfacePointsByBody(q, 0.0)
        why = (RobotCollisionReason(pts, ctx.fruit_sdf, ctx.branch_distance,
                                    cfg.collision_margin, ctx.fruit_box, ctx.branch_box,
                                    cfg.robot_fruit_margin)
               or _OtherLeafReason(ctx, cfg, pts))
        if why:
            return f"{why} along the executed {c.action.family}"
    return ""


def NoActionReason(cands: list[Candidate], dropped_grasps: list[dict],
                   cfg: PlannerConfig) -> str:
    """Why no candidate is left, never empty: the rejection reasons grouped
    by wording with counts, or why no candidate was generated."""
    if not cands:
        n, k = cfg.num_grasps, len(dropped_grasps)
        why = dropped_grasps[0].get("reason", "unknown reason") if k else ""
        no_dir = (f"no pull direction within planner.max_branch_angle_deg "
                  f"({cfg.max_branch_angle_deg:g} deg) of the line to the branch")
        if k >= n:
            return f"no candidates were generated: all {k} grasps were dropped ({why})"
        if k:
            return (f"no candidates were generated: {k} of {n} grasps were dropped ({why}), "
                    f"the other {n - k} have {no_dir}")
        return f"no candidates were generated: the {n} grasps have {no_dir}"
    return GroupReasons([c.reason.split(" (")[0] for c in cands])


_NUMBER = re.compile(r"\d[\d.]*(?:e[+-]?\d+)?")


def GroupReasons(reasons: list[str]) -> str:
    """Rejection reasons grouped by wording, most frequent first, with their
    counts; the numbers in a group's wording given as their range over the
    group (``predicted visibility 0.61-0.95 not above the current 0.97 +
    0.05: 9``)."""
    groups: dict[str, list[str]] = {}
    for r in reasons:
        groups.setdefault(_NUMBER.sub("\0", r) or "unknown", []).append(r or "unknown")
    parts = []
    for key, texts in sorted(groups.items(), key=lambda kv: -len(kv[1])):
        slots = list(zip(*[_NUMBER.findall(t) for t in texts]))
        shown = []
        for vals in slots:
            nums = [float(v.rstrip(".")) for v in vals]
            lo, hi = vals[int(np.argmin(nums))], vals[int(np.argmax(nums))]
            shown.append(lo if min(nums) == max(nums) else f"{lo}-{hi}")
        it = iter(shown)
        parts.append(re.sub("\0", lambda _: next(it), key) + f": {len(texts)}")
    return ", ".join(parts)


def _PredictLive(ctx: PlanningContext, cset: CandidateSet, dcfg: DeformationConfig) -> list:
    """Deformation predictions of the set's live actions (the observed leaf
    plus its virtual petiole), timed into ``cset.timings``; an unusable
    scene turns the set's status to 'no_feasible_action'."""
    predictions = []
    t0 = time.perf_counter()
    if cset.status == "ok" and cset.LiveActions():
        leaf = np.vstack([ctx.leaf_W, cset.scene.leaf_attachment_W])
        try:
            predictions = PredictDeformations(leaf, ctx.branch_all_W, cset.LiveActions(), dcfg,
                                              skip_unmodelled=True)
        except ValueError as err:
            cset.status, cset.message = "no_feasible_action", f"deformation model: {err}"
    cset.timings["deformation_s"] = time.perf_counter() - t0
    return predictions


def PlanLmap(ctx: PlanningContext, cfg: PlannerConfig, dcfg: DeformationConfig,
             progress=None) -> PlanResult:
    """The LMAP planner, all three stages (the Diagram wires the same
    stages as ActionCandidates -> DeformationPrediction -> ActionSelection).
    Never raises on a bad scene: returns a status."""
    cset = GenerateCandidates(ctx, cfg, dcfg, progress)
    predictions = _PredictLive(ctx, cset, dcfg)
    result = SelectFromPredictions(ctx, cset, predictions, cfg)
    result.timings["total_s"] = sum(v for k, v in result.timings.items() if k != "total_s")
    return result


# --- re-planning from the held leaf -------------------------------------

# How far (m) the observed leaf can end from the held grasp point because the
# gripper's pads (2.2 x 3.8 cm) hide it from the camera.
HELD_LEAF_HIDDEN = 0.02


@dc.dataclass
class HeldGrasp:
    """The leaf as the gripper holds it after ``motions`` executed motions:
    the first grasp pose (``p_WG0``, ``R_WG0``), the current TCP pose
    (``p_WG``, ``R_WG``, the last motion's planned end), the hinge the arcs
    swing about, and the predicted ARAP energy per leaf node of the motions
    so far (compounded, ``CompoundEnergyPerNode``: each continuation's
    energy is predicted from the leaf as observed before it; the petiole
    bending term is computed on the total turn from the first grasp)."""
    p_WG0: np.ndarray
    R_WG0: np.ndarray
    p_WG: np.ndarray
    R_WG: np.ndarray
    hinge_W: np.ndarray | None
    motions: int
    energy_per_node: float
    twist_rad: float = 0.0     # the executed twists' summed angle (rad)
    families: tuple = ()       # the executed motions' families, in order

    @staticmethod
    def After(plans: list) -> "HeldGrasp":
        """The held state after executing each plan's chosen action in turn
        (``plans[0]`` grasped the leaf)."""
        first, last = plans[0].chosen.action, plans[-1].chosen.action
        e = 0.0
        for p in plans:
            if np.isfinite(p.chosen.arap_energy):
                e = CompoundEnergyPerNode(e, p.chosen.arap_energy
                                          / max(1, p.chosen.num_leaf_nodes))
        twist = sum(abs(p.chosen.action.angle) for p in plans
                    if p.chosen.action.family == "twist")
        return HeldGrasp(first.p_WG, first.R_WG, last.p_WG + last.dp_W, last.R_WG_end,
                         plans[0].hinge_W, len(plans), e, twist,
                         tuple(p.chosen.action.family for p in plans))


def GenerateContinuation(ctx: PlanningContext, cfg: PlannerConfig, dcfg: DeformationConfig,
                         held: HeldGrasp) -> CandidateSet:
    """Candidates continuing from the held leaf (``ctx.scene``: the fused
    re-estimate, its leaf from the newest view; ``ctx.q_current``: the
    joints holding it): pulls and arcs from the current TCP pose, IK and
    robot checks from the current joints; the visibility now counts the
    robot as an occluder (it holds the leaf in front of the camera)."""
    timings = {"generation_collision_s": 0.0, "visibility_s": 0.0}
    if ctx.scene.fruit is None or len(ctx.scene.fruit.faces) == 0:
        return CandidateSet("no_fruit", ctx.scene, timings=timings,
                            message="no fruit estimate: nothing to reveal")
    t0 = time.perf_counter()
    vis = VisibilityModel(ctx.X_WC, FruitSurfaceSamples(ctx.scene.fruit), cfg.visibility_voxel,
                          ctx.image_tan)
    seen_init = vis.Seen(np.vstack([ctx.leaf_W, ctx.occluders_W,
                                    ctx.robot.SurfacePoints(ctx.q_current)]))
    timings["visibility_s"] += time.perf_counter() - t0
    out = CandidateSet("ok", ctx.scene, visibility=vis, seen_init_mask=seen_init,
                       timings=timings, hinge_W=held.hinge_W)
    n_init, n_max = int(seen_init.sum()), int(vis.max_seen.sum())
    if n_max == 0:
        out.status, out.message = "no_fruit", "the fruit estimate is outside camera0's view"
        return out
    if n_init >= cfg.early_stop_fraction * n_max:
        out.status = "no_action_needed"
        out.message = f"fruit already {n_init / n_max:.0%} visible (predicted)"
        return out
    if len(ctx.leaf_W) < 10:
        out.status, out.message = "no_feasible_action", "the held leaf is not seen"
        return out
    t0 = time.perf_counter()
    p, R = held.p_WG, held.R_WG
    actions = []
    families = [f for f in cfg.action_families if f in cfg.continuation_families]
    if "pull" in families:
        dirs, ids = DirectionsForGrasp(p, ctx.branch_all_W, cfg.max_branch_angle_deg,
                                       PullDirections()[:cfg.num_directions])
        actions += [Action(p, R, s * u, grasp_id=0, direction_id=int(j))
                    for u, j in zip(dirs, ids) for s in cfg.distances]
    if held.hinge_W is not None and np.linalg.norm(p - held.hinge_W) > 0.02:
        if "arc" in families:
            actions += MakeArcActions(p, R, held.hinge_W, HingeAxes(p, held.hinge_W,
                                                                    cfg.num_arc_axes),
                                      np.deg2rad(np.asarray(cfg.arc_angles_deg, float)),
                                      grasp_id=0)
        if "twist" in families:
            actions += MakeTwistActions(p, R, held.hinge_W,
                                        np.deg2rad(np.asarray(cfg.twist_angles_deg, float)),
                                        grasp_id=0)
    cands = [Candidate(a, _DistanceId(a, cfg)) for a in actions]
    out.candidates = _MotionChecks(ctx, cfg, cands, np.asarray(ctx.q_current, float))
    timings["generation_collision_s"] += time.perf_counter() - t0
    out.scene, msg = AttachLeaf(ctx.scene, dcfg)
    out.message = msg
    return out


def PlanContinuation(ctx: PlanningContext, cfg: PlannerConfig, dcfg: DeformationConfig,
                     held: HeldGrasp, progress=None) -> PlanResult:
    """A further motion from the held leaf (``GenerateContinuation``), its
    deformation predicted on the leaf as observed now (the graph continues
    from the observed deformed leaf, the gripper as its handle), selected
    as the first motion is, with the energy cap applied to the motions'
    compounded energy per node (``CompoundEnergyPerNode``). Never raises on
    a bad scene."""
    progress = progress or (lambda m: None)
    if "pull" in held.families and not cfg.continue_after_pull:
        result = PlanResult("no_feasible_action", cfg.method,
                            message="no further motion after a straight pull "
                                    "(planner.continue_after_pull: false)")
        progress(f"continuation: {result.status} ({result.message})")
        return result
    # The pads hide the held leaf around the grasp from the camera: the
    # nearest observed leaf point can be up to about half a pad away.
    dcfg = dc.replace(dcfg, max_grasp_distance=dcfg.max_grasp_distance + HELD_LEAF_HIDDEN)
    cset = GenerateContinuation(ctx, cfg, dcfg, held)
    predictions = _PredictLive(ctx, cset, dcfg)
    result = SelectFromPredictions(ctx, cset, predictions, cfg,
                                   energy_offset_per_node=held.energy_per_node,
                                   hinge_reference_W=held.p_WG0,
                                   min_gain=cfg.min_replan_gain,
                                   twist_offset_rad=held.twist_rad)
    result.timings["total_s"] = sum(v for k, v in result.timings.items() if k != "total_s")
    progress(f"continuation: {result.status}" + (f" ({result.message})" if result.message else ""))
    return result


# --- baselines ----------------------------------------------------------

def _BaselineCandidates(ctx: PlanningContext, cfg: PlannerConfig, distance: float,
                        directions: np.ndarray) -> list[tuple]:
    """IK-feasible (grasp, direction) actions at one ``distance``, without
    the LMAP checks. Returns (grasp, Candidate) pairs."""
    grasps, _ = GraspCandidates(ctx.leaf_W, np.zeros((0, 3)), ctx.p_WC, cfg.num_grasps,
                                cfg.grasp_inset, 0.0)
    out = []
    for g in grasps:
        actions = [Action(g.p_WG, g.R_WG, distance * u, grasp_id=g.grasp_id, direction_id=j)
                   for j, u in enumerate(directions)]
        cfg_nocheck = dc.replace(cfg, collision_margin=-np.inf)
        for c in _IkAndRobotChecks(ctx, g, cfg_nocheck, actions):
            if c.q_pulled is not None and not c.reason:
                out.append((g, c))
    return out


def PlanBaseline(ctx: PlanningContext, cfg: PlannerConfig, method: str, distance: float,
                 seed: int = 0) -> PlanResult:
    """``random``: uniform over IK-feasible candidates (any grasp, any of the
    14 directions) at ``distance``. ``upward`` / ``min_overlap``: drop
    actions whose robot comes within the margin of visible fruit or branch
    points, take the grasp farthest from the branch, and pull along +z
    (upward) or along the direction whose projected robot overlaps the
    projected leaf least (min_overlap)."""
    t0 = time.perf_counter()
    if ctx.scene.semantic.leaf_points_W.shape[0] < 10:
        return PlanResult("no_feasible_action", method, message="no leaf points")
    if method == "random":
        cands = _BaselineCandidates(ctx, cfg, distance, PullDirections())
        if not cands:
            return PlanResult("no_feasible_action", method, message="no IK-feasible action")
        rng = np.random.default_rng(seed)
        chosen = cands[int(rng.integers(len(cands)))][1]
        return PlanResult("ok", method, chosen=chosen, candidates=[c for _, c in cands],
                          timings={"total_s": time.perf_counter() - t0})
    if method not in ("upward", "min_overlap"):
        raise ValueError(f"unknown baseline {method!r}")
    dirs = np.array([[0.0, 0.0, 1.0]]) if method == "upward" else PullDirections()
    cands = _BaselineCandidates(ctx, cfg, distance, dirs)
    plant_pts = np.vstack([ctx.scene.semantic.fruit_points_W, ctx.branch_obs_W])
    from scipy.spatial import cKDTree
    tree = cKDTree(plant_pts) if len(plant_pts) else None
    safe = []
    for g, c in cands:
        pts = ctx.robot.SurfacePoints(c.q_pulled)
        if tree is not None and tree.query(pts, distance_upper_bound=cfg.collision_margin)[0].min() \
                < cfg.collision_margin:
            c.reason = "robot near visible plant points"
            continue
        safe.append((g, c))
    if not safe:
        return PlanResult("no_feasible_action", method, candidates=[c for _, c in cands],
                          message="every action comes near visible plant points")
    if len(ctx.branch_obs_W):
        far = lambda g: cKDTree(ctx.branch_obs_W).query(g.p_WG)[0]
    else:
        far = lambda g: 0.0
    best_grasp = max({id(g): g for g, _ in safe}.values(), key=far)
    mine = [c for g, c in safe if g is best_grasp]
    if method == "upward":
        chosen = mine[0]
    else:
        vis_cam = np.linalg.inv(np.asarray(ctx.X_WC, float))
        f = 300.0

        def pixels(p):
            p_C = p @ vis_cam[:3, :3].T + vis_cam[:3, 3]
            uv = np.round(f * p_C[:, :2] / np.maximum(p_C[:, 2:3], 1e-3)).astype(int)
            return set(map(tuple, uv))
        leaf_pix = pixels(ctx.leaf_W)
        chosen = min(mine, key=lambda c: len(pixels(ctx.robot.SurfacePoints(c.q_pulled))
                                             & leaf_pix))
    return PlanResult("ok", method, chosen=chosen, candidates=[c for _, c in cands],
                      timings={"total_s": time.perf_counter() - t0})
