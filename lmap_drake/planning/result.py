"""The planner's records: one action's checks and scores (``Candidate``),
stage 1's output (``CandidateSet``) and the answer (``PlanResult``, with
its JSON form). World frame W, metres; visibility counts are 3 mm fruit
voxels."""
from __future__ import annotations

import dataclasses as dc
import json
from pathlib import Path

import numpy as np

from lmap_drake.deformation.action import Action
from lmap_drake.planning.config import PlannerConfig
from lmap_drake.planning.visibility import VisibilityModel
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
    # the largest push (m) the robot makes on a leaf it does not hold, over
    # the approach and the action's checked poses (``planner.max_brush_displacement``)
    brush_displacement: float = 0.0

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
                "brush_displacement": (None if self.approach is None
                                       else round(float(self.brush_displacement), 4)),
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
    # m: how far the true attachment may be from hinge_W (``planner.hinge_error``
    # or the unseen petiole's length, ``attachment.UnseenPetiole``)
    hinge_error_m: float | None = None
    # Several fruits (``planner.targets: all``): which fruit this plan is for
    # and which leaf it moves, and why (JSON-able; see systems.planning.PlantPlanning).
    target: dict | None = None
    # which fruit shapes the checks and the visibility used (``planner.fruit_shapes``,
    # ``visibility_shapes``; ``context.FruitShapesRecord``); None: no fruit
    fruit_shapes: dict | None = None
    # Fruit instances that are no target (``targets.SkippedFruits``: low
    # segmentation confidence or an implausible completed shape), with why.
    skipped_fruits: list = dc.field(default_factory=list)

    def Summary(self) -> dict:
        out = {"status": self.status, "method": self.method, "message": self.message,
               "seen_init": self.seen_init, "seen_max": self.seen_max,
               "timings": self.timings, "num_candidates": len(self.candidates),
               "num_feasible": sum(c.feasible for c in self.candidates),
               "dropped_grasps": self.dropped_grasps,
               "hinge_W": None if self.hinge_W is None else np.round(self.hinge_W, 4).tolist(),
               "hinge_error_m": (None if self.hinge_error_m is None
                                 else round(float(self.hinge_error_m), 4))}
        if self.target is not None:
            out["target"] = self.target
        if self.fruit_shapes is not None:
            out["fruit_shapes"] = self.fruit_shapes
        if self.skipped_fruits:
            out["skipped_fruits"] = self.skipped_fruits
        if self.chosen is not None:
            out["chosen"] = self.chosen.Row()
        return out

    def SaveJson(self, path: str | Path) -> None:
        data = self.Summary()
        data["candidates"] = [c.Row() for c in self.candidates]
        Path(path).write_text(json.dumps(data, indent=1))


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
    hinge_error_m: float | None = None  # m: how far the true attachment may be from it

    def LiveActions(self) -> list[Action]:
        """Actions still feasible after IK and robot checks (for deformation)."""
        return [c.action for c in self.candidates if c.feasible]


def DistanceId(a: Action, cfg: PlannerConfig) -> int:
    """Index of the action's distance in ``planner.distances`` (pulls) or
    of its angle in ``planner.arc_angles_deg`` (arcs)."""
    if a.family != "pull":
        deg = np.asarray(cfg.arc_angles_deg if a.family == "arc" else cfg.twist_angles_deg,
                         float)
        return int(np.argmin(np.abs(deg - np.rad2deg(abs(a.angle)))))
    return int(round(a.distance / 0.02)) - 1
