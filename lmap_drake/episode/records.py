"""What an episode writes: ``EpisodeResult`` (what ``RunEpisode``
returns), ``SaveEpisode`` (``episode.json``, ``plan.json``,
``candidates.json``, the recording, images and figures), ``PlanRecord``
(``plan.json``, the same for a run and its replay) and the one-line texts of
a plan (``DescribePlan``) and an outcome (``OutcomeLine``).
"""
from __future__ import annotations

import dataclasses as dc
import json
from pathlib import Path

import numpy as np

from lmap_drake.episode.figures import SaveEpisodeFigures
from lmap_drake.perception.points import Intrinsics
from lmap_drake.perception.recording import SaveRecording
from lmap_drake.planning.selection import RejectionCounts
from lmap_drake.scenario import Scenario
from lmap_drake.viz import SaveDepth, SaveLabel, SaveRgb


@dc.dataclass
class EpisodeResult:
    """What ``RunEpisode`` returns (``SaveEpisode`` writes it)."""
    record: dict
    world: object
    images_before: dict | None
    images_after: dict | None
    status: object
    views: tuple = ()


def DescribePlan(plan) -> str:
    """The chosen action, its predicted energy and visibility, in one line."""
    c = plan.chosen
    a = c.action
    if c.approach is None:        # a continuation: the leaf is already held
        where = f"holding the leaf at {np.round(a.p_WG, 3).tolist()} m, "
    else:
        where = f"grasp {a.grasp_id} at {np.round(a.p_WG, 3).tolist()} m, "
    vis = (f"{c.seen / plan.seen_max:.2f} (from {plan.seen_init / plan.seen_max:.2f})"
           if plan.seen_max and c.seen >= 0 else "n/a")
    e = c.EnergyPerNode()
    how = (f"pull {a.distance * 100:.0f} cm along "
           f"{np.round(a.dp_W / max(a.distance, 1e-9), 2).tolist()}" if a.family == "pull" else
           f"{a.Describe()} about {np.round(a.axis_W, 2).tolist()} through the estimated "
           f"petiole attachment {np.round(a.pivot_W, 3).tolist()} m")
    return (f"{where}{how}"
            f"; predicted visibility {vis}; predicted energy per node "
            + (f"{e:.2e} m^2" if e is not None else "n/a"))


def HypothesesRecord(estimate) -> dict | None:
    """The fruit's shape hypotheses of a ``SceneEstimate`` (or a
    ``PlantEstimate``: its fruits' in a list) in JSON form
    (``ShapeHypotheses.Record``); None without any."""
    if estimate is None:
        return None
    fruits = getattr(estimate, "fruits", None)
    if fruits is not None:
        recs = [f.hypotheses.Record() if getattr(f, "hypotheses", None) is not None else None
                for f in fruits]
        return {"fruits": recs} if any(r is not None for r in recs) else None
    f = getattr(estimate, "fruit", None)
    h = getattr(f, "hypotheses", None)
    return h.Record() if h is not None else None


def PlanRecord(plan, stage_seconds: dict | None = None, estimate=None) -> dict:
    """``plan.json``: the planner's answer (status, chosen action, predicted
    visibility, stage timings), the same for a run and its replay; with the
    ``estimate`` planned on, its fruit's shape hypotheses
    (``shape_hypotheses``, ``HypothesesRecord``)."""
    if plan is None:
        return {"status": None, "shape_hypotheses": HypothesesRecord(estimate)}
    out = {"status": plan.status, "method": plan.method, "message": plan.message,
           "chosen_action": plan.chosen.Row() if plan.chosen is not None else None,
           "action": plan.chosen.action.Describe() if plan.chosen is not None else None,
           "predicted_visibility": None if not plan.seen_max else {
               "initial": plan.seen_init / plan.seen_max,
               "chosen": (plan.chosen.seen / plan.seen_max
                          if plan.chosen is not None and plan.chosen.seen >= 0 else None)},
           "num_candidates": len(plan.candidates),
           # after every check (robot, deformation, leaf-fruit, visibility
           # gain, caps, the executed path): feasible and not chosen =
           # passed all, scored lower
           "num_feasible": sum(c.feasible for c in plan.candidates),
           "rejected": RejectionCounts(plan.candidates),
           # the fruit shapes the robot-fruit and leaf-fruit checks kept clear
           # of and the visibility averaged over (planner.fruit_shapes,
           # planner.visibility_shapes), with the hypotheses' volume interval
           "fruit_shapes": getattr(plan, "fruit_shapes", None)}
    if getattr(plan, "target", None):
        out["target"] = plan.target        # which fruit, its occluders, why
    if getattr(plan, "skipped_fruits", None):
        out["skipped_fruits"] = plan.skipped_fruits    # fruit instances that are no target
    if stage_seconds is not None:
        out["stage_seconds"] = stage_seconds
    out["shape_hypotheses"] = HypothesesRecord(estimate)
    return out


def RecordingCamera(scenario: Scenario, clients=None) -> tuple[dict, np.ndarray]:
    """(camera dict, X_WC 4x4) of camera0 as the episode used it."""
    cam = scenario.cameras["camera0"]
    K = Intrinsics.FromCameraConfig(cam)
    info = {"width": K.width, "height": K.height, "fx": K.fx, "fy": K.fy, "cx": K.cx,
            "cy": K.cy}
    if clients is not None:
        info["serial"] = str(getattr(clients.camera, "serial", ""))
        info["depth_scale"] = float(getattr(clients.camera, "depth_scale", float("nan")))
    return info, cam.X_PB.GetDeterministicValue().GetAsMatrix4()


def SaveEpisode(result: EpisodeResult, out: Path, clients=None) -> list[str]:
    """Writes ``episode.json``, ``plan.json``, ``candidates.json``, the
    recording, RGB/depth of view 0 (and label in simulation), view 1, the
    images with the segmentation overlaid, the plan over the camera image
    and the shape pictures."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    world = result.world
    (out / "episode.json").write_text(json.dumps(result.record, indent=2, default=float))
    files = ["episode.json"]
    plan = result.status.plan
    (out / "plan.json").write_text(json.dumps(PlanRecord(
        plan, result.status.stage_seconds, getattr(result.status, "initial_estimate", None)),
        indent=1, default=float))
    files.append("plan.json")
    if plan is not None:
        plan.SaveJson(out / "candidates.json")
        files.append("candidates.json")
    # every re-plan from the held leaf, executed or not (its status says)
    for k, cont in enumerate(result.status.replan_results, start=1):
        cont.SaveJson(out / f"continuation_{k}.json")
        files.append(f"continuation_{k}.json")
    camera, X_WC = RecordingCamera(world.scenario, clients)
    files += SaveRecording(out, result.views, camera, X_WC,
                           "hardware" if world.hardware else "simulation")
    if result.images_before is not None:
        SaveRgb(result.images_before["rgb_image"], out / "rgb.png")
        SaveDepth(result.images_before["depth_image"], out / "depth.png")
        files += ["rgb.png", "depth.png"]
        if not world.hardware:
            SaveLabel(result.images_before["label_image"], out / "label.png")
            files.append("label.png")
    if len(result.views) >= 2 and result.images_after is not None:
        SaveRgb(result.images_after["rgb_image"], out / "rgb_after.png")
        files.append("rgb_after.png")
        if not world.hardware:
            SaveLabel(result.images_after["label_image"], out / "label_after.png")
            files.append("label_after.png")
    files += SaveEpisodeFigures(result, out)
    if result.record.get("outcome") is not None:
        (out / "outcome.json").write_text(json.dumps(result.record["outcome"], indent=2))
        files.append("outcome.json")
    return files


def OutcomeLine(outcome: dict) -> str:
    """The outcome as one line for the terminal (floats to 3 decimals; the
    full values are in ``outcome.json`` / ``episode.json``)."""
    return "outcome: " + ", ".join(f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}"
                                   for k, v in outcome.items())
