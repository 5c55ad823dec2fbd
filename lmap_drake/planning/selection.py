"""LMAP stages 2-3 (paper Sec. III-C-2/3) on the predicted deformations:
energy and petiole limits, leaf-fruit checks, visibility with early stop,
the score argmax(norm N_vis - lambda norm E) with its vetoes (lever and
energy caps), a forced action, and the executed path's check of the
choice; why no action is left, in words. World frame W, metres."""
from __future__ import annotations

import dataclasses as dc
import re
import time

import numpy as np

from lmap_drake.deformation.graph import FREE
from lmap_drake.deformation.predict import UnmodelledGrasp
from lmap_drake.planning.candidates import PlanningError
from lmap_drake.planning.collision import DistanceAnchors, LeafCollisionReason
from lmap_drake.planning.config import PlannerConfig
from lmap_drake.planning.context import FruitShapesRecord, PlanningContext
from lmap_drake.planning.energy import (ARC_REFERENCE_DEG, PULL_LEVER_REFERENCE,
                                        CompoundEnergyPerNode, EquivalentTurnDeg,
                                        HingeRotationDeg, MaxArcAngle, MaxPullDistance,
                                        PetioleBendingEnergy)
from lmap_drake.planning.hazard import MisfitReason, TetherElongation
from lmap_drake.planning.result import Candidate, CandidateSet, PlanResult
from lmap_drake.planning.robot_checks import ActionPathReason
from lmap_drake.planning.visibility import CountNewlySeen


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


def SelectFromPredictions(ctx: PlanningContext, cset: CandidateSet, predictions: list,
                          cfg: PlannerConfig, method: str = "lmap",
                          energy_offset_per_node: float = 0.0,
                          hinge_reference_W: np.ndarray | None = None,
                          min_gain: float = 0.0, twist_offset_rad: float = 0.0,
                          rotation_reference: np.ndarray | None = None) -> PlanResult:
    """Paper Sec. III-C-2/3: leaf-fruit checks, visibility with early stop
    along the distances, and the score. ``predictions`` are aligned with
    ``cset.LiveActions()`` (``PredictedDeformation``: ``energy``,
    ``leaf_points_W`` dense, the observed leaf first). A re-plan from the
    held leaf gives ``hinge_reference_W`` (the first grasp), the motions'
    energy so far (``energy_offset_per_node``), twist
    (``twist_offset_rad``) and first grasp orientation
    (``rotation_reference``, 3x3), and ``min_gain``."""
    # Work on copies: ``cset`` may be a cached Drake output (never mutate it).
    cands = [dc.replace(c) for c in cset.candidates]
    result = _UnselectedResult(cset, cands, method)
    if cset.scene is not None and cset.scene.fruit is not None:
        result.fruit_shapes = FruitShapesRecord(
            cset.scene, getattr(ctx, "fruit_shapes", "estimate"), cfg.visibility_shapes,
            None if cset.visibility is None else cset.visibility.num_shapes)
    if cset.status != "ok":
        return result
    live = [c for c in cands if c.feasible]
    if len(predictions) != len(live):
        raise PlanningError(f"{len(predictions)} predictions for {len(live)} live actions")
    _ApplyPredictions(ctx, cset, cfg, live, predictions, hinge_reference_W, twist_offset_rad)
    t0 = time.perf_counter()
    forced = ForcedCandidate(cands, cfg.force_action)
    _PredictVisibility(ctx, cset, cfg, cands, forced, result.seen_max)
    result.timings["visibility_s"] = result.timings.get("visibility_s", 0.0) + \
        time.perf_counter() - t0
    if min_gain > 0 and result.seen_max:
        _RequireGain(cands, result.seen_init, result.seen_max, min_gain)
    feasible = [c for c in cands if c.feasible]
    if feasible:
        feasible = _ScoreAndVeto(cfg, cset.hinge_W, feasible, energy_offset_per_node,
                                 rotation_reference, cset.hinge_error_m)
    if cfg.force_action:
        return _ChooseForced(result, forced, cfg.force_action)
    return _ChooseExecutable(ctx, cfg, result, feasible, cset.dropped_grasps)


def _UnselectedResult(cset: CandidateSet, cands: list[Candidate], method: str) -> PlanResult:
    """The plan before any selection: ``cset``'s status, message, timings,
    hinge and visibility counts, with ``cands`` (copies of its candidates)."""
    result = PlanResult(cset.status, method, candidates=cands,
                        dropped_grasps=cset.dropped_grasps, timings=dict(cset.timings),
                        message=cset.message, hinge_W=cset.hinge_W,
                        hinge_error_m=cset.hinge_error_m)
    if cset.visibility is not None:
        result.seen_init = cset.visibility.Count(cset.seen_init_mask)
        result.seen_max = cset.visibility.Count(cset.visibility.max_seen)
    return result


def _TurnLimit(cfg: PlannerConfig, replan: bool) -> tuple[str, float]:
    """(key, deg) of the binding limit on the leaf's turn about its
    attachment: ``max_hinge_deg``, and for a re-plan from the held leaf
    also ``max_replan_turn_deg`` (the reason names the binding one)."""
    limits = [("max_hinge_deg", cfg.max_hinge_deg)]
    if replan:
        limits.append(("max_replan_turn_deg", cfg.max_replan_turn_deg))
    return min(limits, key=lambda kv: kv[1])


def _ApplyPredictions(ctx: PlanningContext, cset: CandidateSet, cfg: PlannerConfig,
                      live: list[Candidate], predictions: list,
                      hinge_reference_W: np.ndarray | None, twist_offset_rad: float) -> None:
    """Each live candidate with its prediction: the energy (``_SetEnergy``),
    the turn and tether limits (``_TurnOrTetherReason``) and the predicted
    leaf (the observed leaf's points); an unmodelled grasp is rejected."""
    n_leaf = len(ctx.leaf_W)
    max_turn_key, max_turn = _TurnLimit(cfg, hinge_reference_W is not None)
    for c, p in zip(live, predictions):
        if isinstance(p, UnmodelledGrasp):
            c.reason = f"deformation model: {p.message}"
            continue
        ref = c.action.p_WG if hinge_reference_W is None else hinge_reference_W
        _SetEnergy(c, p, cset.hinge_W, ref, twist_offset_rad, cfg)
        why = _TurnOrTetherReason(c, cset.hinge_W, ref, max_turn_key, max_turn, cfg)
        if why:
            c.reason = why
        c.deformed_leaf_W = np.asarray(p.leaf_points_W)[:n_leaf]


def _SetEnergy(c: Candidate, p, hinge_W: np.ndarray | None, ref_W: np.ndarray,
               twist_offset_rad: float, cfg: PlannerConfig) -> None:
    """``c``'s ARAP energy and deformable node count from its prediction
    ``p``, its equivalent turn about the hinge (from ``ref_W``, with the
    twists so far) and its energy: ARAP plus the petiole's bending."""
    c.arap_energy = float(p.energy)
    c.num_leaf_nodes = int(np.count_nonzero(np.asarray(p.node_kind) == FREE))
    c.hinge_deg = EquivalentTurnDeg(
        HingeRotationDeg(hinge_W, ref_W, c.action.p_WG + c.action.dp_W),
        twist_offset_rad + (abs(c.action.angle) if c.action.family == "twist" else 0.0),
        cfg.petiole_torsion_ratio)
    c.energy = c.arap_energy + c.num_leaf_nodes * PetioleBendingEnergy(
        c.hinge_deg, cfg.hinge_bending_weight)


def _TurnOrTetherReason(c: Candidate, hinge_W: np.ndarray | None, ref_W: np.ndarray,
                        max_turn_key: str, max_turn: float, cfg: PlannerConfig) -> str:
    """'' or why ``c`` loads the petiole too much: it turns the leaf past
    ``max_turn`` about its attachment, or pulls the grasp farther from it
    than ``max_tether_elongation``."""
    if np.isfinite(c.hinge_deg) and c.hinge_deg > max_turn:
        return (f"turns the leaf {c.hinge_deg:.0f} deg about its petiole attachment "
                f"({max_turn_key} {max_turn:g})")
    if hinge_W is not None and cfg.max_tether_elongation > 0:
        # the petiole is stiff along its axis: pulling the grasp away
        # from the attachment loads it, whatever the blade does
        tether = TetherElongation(ref_W, c.action.p_WG + c.action.dp_W, hinge_W)
        if tether > cfg.max_tether_elongation:
            return (f"pulls the grasp {tether * 100:.1f} cm farther from the petiole "
                    f"attachment (max_tether_elongation {cfg.max_tether_elongation:g} m)")
    return ""


class _LeafChecks:
    """The leaf-fruit check of a predicted leaf and, with
    ``planner.check_leaf_branch``, the leaf-branch one; the observed leaf's
    fruit SDF and branch distance are evaluated once, when first needed."""

    def __init__(self, ctx: PlanningContext, cfg: PlannerConfig):
        self.ctx, self.cfg = ctx, cfg
        self.rest_sdf = None       # the fruit SDF at the observed leaf
        self.rest_branch = None    # the branch distance there
        self.anchors = None        # the fruits' mesh distances there (``DistanceAnchors``)

    def FruitReason(self, deformed_leaf_W: np.ndarray) -> str:
        """The leaf-fruit check alone."""
        ctx = self.ctx
        if self.rest_sdf is None and ctx.fruit_sdf is not None:
            self.rest_sdf = np.asarray(ctx.fruit_sdf(ctx.leaf_W), float)
            self.anchors = DistanceAnchors(ctx.fruit_sdf, ctx.leaf_W)
        return LeafCollisionReason(ctx.leaf_W, deformed_leaf_W, ctx.fruit_sdf,
                                   self.cfg.collision_margin, ctx.fruit_box, self.rest_sdf,
                                   anchors=self.anchors)

    def Reason(self, deformed_leaf_W: np.ndarray) -> str:
        ctx, cfg = self.ctx, self.cfg
        why = self.FruitReason(deformed_leaf_W)
        if not why and cfg.check_leaf_branch and ctx.branch_distance is not None:
            # the held leaf swung into a stem or shoot (the FEM leaf
            # then presses it, loading its own petiole); points resting
            # on a branch (the petiole's base) are not counted
            if self.rest_branch is None:
                self.rest_branch = np.asarray(ctx.branch_distance(ctx.leaf_W), float)
            why = LeafCollisionReason(ctx.leaf_W, deformed_leaf_W, ctx.branch_distance,
                                      cfg.collision_margin, ctx.branch_box, self.rest_branch,
                                      what="branch", ignore_touching=True)
        return why

    def PushedBackReason(self, action) -> str:
        """The leaf-fruit check of the observed leaf shifted back whole by
        a straight pull's push away from the camera (``PushedBackLeaf``;
        '' for turns and pulls toward the camera)."""
        if action.family != "pull":
            return ""
        pushed, s = PushedBackLeaf(self.ctx.leaf_W, self.ctx.p_WC, action.p_WG, action.dp_W)
        if pushed is None:
            return ""
        # the fruit only: shifted whole, the blade's base would enter the
        # branch it hangs from
        why = self.FruitReason(pushed)
        return f"{why} if pushed back {s * 100:.1f} cm" if why else ""


def PushedBackLeaf(leaf_W: np.ndarray, p_WC: np.ndarray, p_WG: np.ndarray,
                   dp_W: np.ndarray) -> tuple[np.ndarray | None, float]:
    """The leaf points (N, 3; W, m) shifted by the part of a grasp motion
    ``dp_W`` (m) along the ray from the camera ``p_WC`` through the grasp
    ``p_WG``, and that part s (m); (None, s) when the motion does not move
    the grasp away from the camera (s <= 0). A blade pushed back at one
    point can slide back whole on its petiole (``planner.push_back_check``)."""
    ray = np.asarray(p_WG, float) - np.asarray(p_WC, float)
    n = np.linalg.norm(ray)
    if n == 0:
        return None, 0.0
    ray /= n
    s = float(np.asarray(dp_W, float) @ ray)
    if s <= 0:
        return None, s
    return np.asarray(leaf_W, float) + s * ray, s


def _PredictVisibility(ctx: PlanningContext, cset: CandidateSet, cfg: PlannerConfig,
                       cands: list[Candidate], forced: Candidate | None, n_max: int) -> None:
    """Along each (grasp, direction)'s distances, shortest first: the leaf
    checks (``_LeafChecks``) and the predicted visibility (``seen``,
    ``n_vis``) of each candidate still feasible (and of a forced one); the
    distances beyond the first that reaches ``early_stop_fraction`` of
    ``n_max`` are rejected."""
    vis, seen_init = cset.visibility, cset.seen_init_mask
    by_dir: dict[tuple, list[Candidate]] = {}
    for c in cands:
        by_dir.setdefault((c.action.grasp_id, c.action.direction_id), []).append(c)
    leaf_checks = _LeafChecks(ctx, cfg)
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
            why = leaf_checks.Reason(c.deformed_leaf_W)
            if not why and cfg.push_back_check:
                why = leaf_checks.PushedBackReason(c.action)
            if why:
                c.reason = c.reason or why
                if not is_forced:
                    continue
            if static_zbuf is None:     # these occlude the same for every action
                static_zbuf = vis.ZBuffer(ctx.occluders_W)
            seen = vis.Seen(np.vstack([c.deformed_leaf_W,
                                       ctx.robot.SurfacePoints(c.q_pulled)]), static_zbuf)
            c.seen = vis.Count(seen)
            c.n_vis = CountNewlySeen(seen, seen_init, vis)
            if c.seen >= cfg.early_stop_fraction * n_max:
                reached = True


def RejectAll(cands: list[Candidate], reason: str) -> None:
    """Marks every still-feasible candidate of ``cands`` rejected for
    ``reason`` (a stage after the geometric checks failed for all, e.g. the
    deformation model), so that feasibility counts every check."""
    for c in cands:
        if c.feasible:
            c.reason = reason


def _RequireGain(cands: list[Candidate], seen_init: int, n_max: int, min_gain: float) -> None:
    """An action must show clearly more of the fruit than the leaf left
    (or held) where it is (``min_gain`` of its ``n_max`` voxels over
    ``seen_init``): the normalised score alone would pick some action even
    if every one reveals less."""
    for c in cands:
        if c.feasible and c.seen < seen_init + min_gain * n_max:
            c.reason = (f"predicted visibility {c.seen / n_max:.2f} not above the "
                        f"current {seen_init / n_max:.2f} + {min_gain:g}")


def _ScoreAndVeto(cfg: PlannerConfig, hinge_W: np.ndarray | None, feasible: list[Candidate],
                  energy_offset_per_node: float,
                  rotation_reference: np.ndarray | None = None,
                  hinge_error_m: float | None = None) -> list[Candidate]:
    """Scores ``feasible`` (``SelectAction``), then vetoes by the lever caps
    (``_LeverCapReason``), the hinge misfit (``hazard.MisfitReason``, the
    turn counted from ``rotation_reference`` when re-planning, the hinge
    ``hinge_error_m`` off; None: ``planner.hinge_error``) and the
    energy cap (``_EnergyCapReason``); returns the candidates still
    feasible."""
    # The paper's score, normalised over every action that passed the
    # checks; the energy cap and the pull cap then filter (normalising
    # over the capped set instead would shift the lambda trade-off: a
    # veto should not re-rank what it leaves).
    SelectAction(feasible, cfg.energy_weight)
    for c in feasible:
        why = _LeverCapReason(cfg, c, hinge_W) or MisfitReason(
            c.action, hinge_W, rotation_reference,
            cfg.hinge_error if hinge_error_m is None else hinge_error_m, cfg.max_hinge_misfit)
        if why:
            c.reason = why
    feasible = [c for c in feasible if c.feasible]
    cap = cfg.max_energy_per_node
    if cap > 0:
        for c in feasible:
            why = _EnergyCapReason(c, cap, energy_offset_per_node)
            if why:
                c.reason = why
        feasible = [c for c in feasible if c.feasible]
    return feasible


def _LeverCapReason(cfg: PlannerConfig, c: Candidate, hinge_W: np.ndarray | None) -> str:
    """'' or why ``c`` goes too far for its grasp's lever to the
    attachment: a pull longer than ``MaxPullDistance``, an arc wider than
    ``MaxArcAngle`` (twists: ``hazard.MisfitReason``)."""
    if c.action.family == "pull":
        longest = MaxPullDistance(cfg, c.action.p_WG, hinge_W)
        if c.action.distance > longest + 1e-9:
            return (f"a {c.action.distance * 100:.0f} cm straight pull from a grasp "
                    f"this near the attachment (at most {longest * 100:.1f} cm: "
                    f"max_pull_distance {cfg.max_pull_distance:g} m at a "
                    f"{PULL_LEVER_REFERENCE * 100:.0f} cm lever)")
    elif c.action.family == "arc":
        widest = MaxArcAngle(cfg, c.action.p_WG, hinge_W)
        deg = float(np.degrees(abs(c.action.angle)))
        if deg > widest + 1e-6:
            return (f"a {deg:.0f} deg arc from a grasp this near "
                    f"the attachment (at most {widest:.0f} deg: "
                    f"{ARC_REFERENCE_DEG:.0f} deg at arc_lever_reference "
                    f"{cfg.arc_lever_reference * 100:g} cm)")
    return ""


def _EnergyCapReason(c: Candidate, cap: float, energy_offset_per_node: float) -> str:
    """'' or why ``c``'s predicted energy per leaf node (compounded with the
    motions' so far, ``CompoundEnergyPerNode``) is above ``cap``."""
    e = c.EnergyPerNode()
    if e is not None and energy_offset_per_node > 0:
        arap = c.arap_energy / max(1, c.num_leaf_nodes)
        e = CompoundEnergyPerNode(energy_offset_per_node, arap) + (e - arap)
    if e is not None and e > cap:
        return (f"predicted energy per leaf node {e:.2e} m^2 above "
                f"max_energy_per_node {cap:.2e} (damage risk)")
    return ""


def _ChooseExecutable(ctx: PlanningContext, cfg: PlannerConfig, result: PlanResult,
                      feasible: list[Candidate], dropped_grasps: list[dict]) -> PlanResult:
    """``result`` with the best-scoring feasible action whose executed path
    (as the controller will run it, ``ActionPathReason``) passes; a failing
    one is rejected and the next best taken. None left: status
    'no_feasible_action' and why (``NoActionReason``)."""
    while feasible:
        best = max(feasible, key=lambda c: c.score)
        why = ActionPathReason(ctx, cfg, best)
        if not why:
            result.chosen = best
            return result
        best.reason = why
        feasible = [c for c in feasible if c.feasible]
    result.status = "no_feasible_action"
    result.message = "no feasible action: " + NoActionReason(result.candidates,
                                                             dropped_grasps, cfg)
    return result


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


def RejectionCounts(cands: list[Candidate]) -> dict[str, int]:
    """The rejected candidates' reasons grouped as ``GroupReasons`` words
    them (numbers as ranges), each with its count, most frequent first."""
    return dict(ReasonGroups([c.reason.split(" (")[0] for c in cands if not c.feasible]))


def GroupReasons(reasons: list[str]) -> str:
    """Rejection reasons grouped by wording, most frequent first, with their
    counts; the numbers in a group's wording given as their range over the
    group (``predicted visibility 0.61-0.95 not above the current 0.97 +
    0.05: 9``)."""
    return ", ".join(f"{text}: {n}" for text, n in ReasonGroups(reasons))


def ReasonGroups(reasons: list[str]) -> list[tuple[str, int]]:
    """(wording with number ranges, count) per group of ``GroupReasons``."""
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
        parts.append((re.sub("\0", lambda _: next(it), key), len(texts)))
    return parts
