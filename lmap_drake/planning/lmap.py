"""Leaf Manipulation Action Planning (paper Sec. III-C), all three stages:
candidates with IK and robot checks (``candidates.GenerateCandidates``),
deformation prediction (``PredictLive``) and selection
(``selection.SelectFromPredictions``). The parts: ``context`` (inputs),
``result`` (records), ``candidates`` (grasps and actions), ``approach`` and
``robot_checks`` (IK and robot checks), ``attachment`` (hinge, virtual
petiole), ``energy`` (petiole load and caps), ``selection``,
``continuation`` (re-plans from a held leaf), ``baselines`` (Random, Upward,
Min-Overlap), ``targets`` (plants with several fruits). World frame W,
metres, seconds."""
from __future__ import annotations

import time

import numpy as np

from lmap_drake.deformation.predict import PredictDeformations
from lmap_drake.planning.candidates import GenerateCandidates
from lmap_drake.planning.config import PlannerConfig
from lmap_drake.planning.context import PlanningContext
from lmap_drake.planning.result import CandidateSet, PlanResult
from lmap_drake.planning.selection import RejectAll, SelectFromPredictions
from lmap_drake.deformation.config import DeformationConfig


def PredictLive(ctx: PlanningContext, cset: CandidateSet, dcfg: DeformationConfig) -> list:
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
            RejectAll(cset.candidates, f"deformation model: {err}")
    cset.timings["deformation_s"] = time.perf_counter() - t0
    return predictions


def PlanLmap(ctx: PlanningContext, cfg: PlannerConfig, dcfg: DeformationConfig,
             progress=None) -> PlanResult:
    """The LMAP planner, all three stages (the Diagram wires the same
    stages as ActionCandidates -> DeformationPrediction -> ActionSelection).
    Never raises on a bad scene: returns a status."""
    cset = GenerateCandidates(ctx, cfg, dcfg, progress)
    predictions = PredictLive(ctx, cset, dcfg)
    result = SelectFromPredictions(ctx, cset, predictions, cfg,
                                   min_gain=cfg.min_visibility_gain)
    result.timings["total_s"] = sum(v for k, v in result.timings.items() if k != "total_s")
    return result
