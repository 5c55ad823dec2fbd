"""``ReplayRun`` (``lmap-drake replay``): re-plans offline on the view a
run recorded (``perception.recording``), with the run's scenario, and says
whether the replay chose the run's action.
"""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Callable

from lmap_drake.diagram import EpisodeResources, MakeReplayDiagram
from lmap_drake.episode.figures import Overlay, PlanOnImage
from lmap_drake.episode.records import DescribePlan, PlanRecord
from lmap_drake.limits import MAX_PLAN_JSON_BYTES, ReadBounded
from lmap_drake.perception.points import Intrinsics
from lmap_drake.perception.recording import LoadRecording, RecordingError
from lmap_drake.perception.segmentation import MakeSegmenter
from lmap_drake.scenario import (DumpScenario, IsEmptyOverride, LoadScenario, RawYaml, Scenario,
                                 ScenarioWithCamera)
from lmap_drake.systems.view_recorder import RecordedViews
from lmap_drake.viz import SavePng


def ReadRunPlan(run_dir: Path) -> dict | None:
    """The chosen action of the run's ``plan.json`` (None: no file, or the
    run chose nothing); ``RecordingError`` naming the file when it is not a
    plan (checked before anything is planned)."""
    plan_file = Path(run_dir) / "plan.json"
    if not plan_file.exists():
        return None
    try:
        plan = json.loads(ReadBounded(plan_file, MAX_PLAN_JSON_BYTES, "plan file").decode())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise RecordingError(f"the run's {plan_file} cannot be read: "
                             f"{' '.join(str(err).split())[:160]}") from None
    chosen = plan.get("chosen_action") if isinstance(plan, dict) else None
    if not isinstance(plan, dict) or not (chosen is None or (
            isinstance(chosen, dict)
            and all(k in chosen for k in ("grasp_id", "direction_id", "distance")))):
        raise RecordingError(f"the run's {plan_file} is not a plan: expected an object whose "
                             f"chosen_action is null or has grasp_id, direction_id, distance")
    return chosen


def _SetsNoReturnRange(scenario_text: str) -> bool:
    """True when ``scenario_text`` itself sets ``perception.no_return_free_range``
    (a hardware capture's no-return pixels then carve as it says, e.g. a bag
    written from a simulated capture, whose no-return pixels are empty space)."""
    if IsEmptyOverride(scenario_text):
        return False
    raw = RawYaml(scenario_text, "--scenario_text")
    return isinstance(raw, dict) and isinstance(raw.get("perception"), dict) and \
        "no_return_free_range" in raw["perception"]


def ReplayRun(run_dir: Path, out: Path, scenario_text: str = "{}",
              progress: Callable[[str], None] = print) -> tuple[list[str], dict]:
    """Re-runs perception, shape completion and planning on the view a run
    recorded (``run_dir/recording``), with the run's ``scenario.yaml`` and
    ``scenario_text`` overrides (a hardware capture's
    ``perception.no_return_free_range`` is 0 unless ``scenario_text`` sets
    it). Writes ``scenario.yaml``, ``plan.json``,
    ``candidates.json``, ``replay.json`` (the run's and the replay's chosen
    action, same or not, timings), ``rgb_before_segmented.png`` and
    ``plan_on_image.png``. Returns (files, replay record)."""
    run_dir, out = Path(run_dir), Path(out)
    recording = LoadRecording(run_dir)
    # the run's plan, read before this replay writes its own (a bag is
    # converted into the replay's own folder); no plan.json: nothing to compare
    had_plan = (run_dir / "plan.json").exists()
    original = ReadRunPlan(run_dir)
    out.mkdir(parents=True, exist_ok=True)
    scenario_file = run_dir / "scenario.yaml"
    if not scenario_file.exists():
        raise RecordingError(f"{scenario_file} not found: a replay needs the run's scenario")
    scenario = LoadScenario(filename=str(scenario_file), scenario_text=scenario_text, bare=True)
    scenario = ScenarioWithCamera(scenario, recording.camera, recording.X_WC)
    if recording.station == "hardware" and not _SetsNoReturnRange(scenario_text):
        scenario.perception.no_return_free_range = 0.0
    if scenario.perception.segmenter == "label" and recording.views[0].label is None:
        raise RecordingError(f"{run_dir}: the recording has no label images (a hardware "
                             f"run); the label segmenter cannot replay it")
    DumpScenario(scenario, out / "scenario.yaml")
    progress(f"replaying view 0 of {recording.folder} ({recording.station} run)")
    t0 = time.perf_counter()
    resources = EpisodeResources.Make(scenario, progress)
    t_load = time.perf_counter() - t0
    diagram = MakeReplayDiagram(scenario, resources, RecordedViews(recording.views, 1))
    ctx = diagram.CreateDefaultContext()

    def timed(name):
        system = diagram.GetSubsystemByName(name)
        port = {"perception": "semantic_scene", "shape_completion": "scene_estimate",
                "action_selection": "plan"}[name]
        t = time.perf_counter()
        value = system.GetOutputPort(port).Eval(system.GetMyContextFromRoot(ctx))
        return value, time.perf_counter() - t
    semantic, seg_s = timed("perception")
    estimate, ssc_s = timed("shape_completion")
    sequence = None
    if scenario.planner.targets == "all":
        t = time.perf_counter()
        sequence, plan, estimate = PlanFruitSequence(diagram, ctx)
        plan_s = time.perf_counter() - t
    else:
        plan, plan_s = timed("action_selection")
    stage_seconds = {"segmentation_s": seg_s, "shape_completion_s": ssc_s,
                     "planning_s": plan_s, **plan.timings}
    files = ["scenario.yaml", "plan.json", "replay.json"]
    (out / "plan.json").write_text(json.dumps(PlanRecord(plan, stage_seconds, estimate), indent=1,
                                              default=float))
    plan.SaveJson(out / "candidates.json")
    files.append("candidates.json")
    mine = plan.chosen.Row() if plan.chosen is not None else None
    # a run without a plan (or whose plan chose nothing) has nothing to compare
    same = None if original is None or not had_plan else (
        mine is not None and all(original[k] == mine[k]
                                 for k in ("grasp_id", "direction_id", "distance")))
    record = {"run": str(run_dir), "scenario_text": scenario_text, "status": plan.status,
              "message": plan.message, "chosen_action": mine, "run_chosen_action": original,
              "same_action_as_run": same,
              "planning_wall_seconds": seg_s + ssc_s + plan_s,
              "template_load_seconds": t_load, "stage_seconds": stage_seconds}
    if sequence is not None:
        record["first_plans"] = sequence
        run_seq = RunFirstPlans(run_dir)
        record["run_first_plans"] = run_seq
        record["same_first_plans_as_run"] = None if run_seq is None else SameFirstPlans(
            sequence, run_seq)
        if run_seq is not None:
            same = record["same_first_plans_as_run"]
    (out / "replay.json").write_text(json.dumps(record, indent=1, default=float))
    files += SavePlanFigures(scenario, recording.views[0], plan, estimate, out)
    progress(f"replay plan {plan.status}: " + (DescribePlan(plan) if plan.chosen is not None
                                               else plan.message))
    what = "first plans (fruit by fruit)" if sequence is not None else "action"
    progress(f"planning on the replayed capture: {record['planning_wall_seconds']:.1f} s; "
             + (f"same {what} as the run" if same else f"different {what} from the run"
                if same is False else "the run had no plan to compare"))
    return files, record


def SavePlanFigures(scenario: Scenario, view, plan, estimate, out: Path) -> list[str]:
    """``rgb_before_segmented.png`` and ``plan_on_image.png`` for one view."""
    cam = scenario.cameras["camera0"]
    K = Intrinsics.FromCameraConfig(cam)
    segmenter = MakeSegmenter(scenario.perception, K)
    seg = segmenter.Segment(view.rgb, view.depth[..., None], None if view.label is None
                            else view.label[..., None])
    SavePng(Overlay(view.rgb, seg.class_map, title=f"segmenter: {segmenter.name} (before)",
                    instance_map=seg.instance_map),
            out / "rgb_before_segmented.png")
    SavePng(PlanOnImage(view.rgb, plan, estimate, K,
                        cam.X_PB.GetDeterministicValue().GetAsMatrix4()),
            out / "plan_on_image.png")
    return ["rgb_before_segmented.png", "plan_on_image.png"]


class _Handled:
    """The ``status`` input of ``plant_planning`` in a replay: the fruits
    the run handled so far, as the ``ArmController``'s status lists them
    (``targets``), with no motion executed."""

    def __init__(self):
        self.targets = []
        self.plan = None
        self.initial_estimate = None


def PlanFruitSequence(diagram, ctx, max_targets: int = 12):
    """``planner.targets: all`` on view 0 as the run did before its first
    motion: the next fruit's plan, and while it is 'no_feasible_action' the
    fruit is recorded as handled and the next one planned (the
    ``ArmController`` does the same). Returns (one record per plan: fruit
    id, leaf id, status, action; the last plan; its scene estimate)."""
    planner = diagram.GetSubsystemByName("plant_planning")
    pctx = planner.GetMyContextFromRoot(ctx)
    status = _Handled()
    seq, plan, scene = [], None, None
    for _ in range(max_targets):
        diagram.GetInputPort("status").FixValue(ctx, status)
        plan = planner.GetOutputPort("plan").Eval(pctx)
        scene = planner.GetOutputPort("scene_estimate").Eval(pctx)
        t = plan.target or {}
        seq.append({"fruit_id": t.get("fruit_id"), "leaf_id": t.get("leaf_id"),
                    "status": plan.status,
                    "action": None if plan.chosen is None else plan.chosen.action.Describe()})
        if plan.status != "no_feasible_action" or not t:
            break
        nxt = _Handled()
        nxt.targets = status.targets + [{"target": t, "outcome": plan.status, "plan": plan,
                                         "initial_estimate": scene, "final_estimate": scene,
                                         "motions": 0}]
        status = nxt
    return seq, plan, scene


def RunFirstPlans(run_dir: Path) -> list[dict] | None:
    """The run's fruit-by-fruit plans before its first motion (its
    ``episode.json`` ``targets``, then, when no fruit moved, the plan it
    stopped at: ``plan.json``): fruit id, leaf id, whether it moved and its
    first motion; None without any."""
    try:
        rows = json.loads((Path(run_dir) / "episode.json").read_text()).get("targets")
    except (OSError, ValueError, AttributeError):
        return None
    if not isinstance(rows, list):
        return None
    out = []
    for r in rows:
        moved = bool(r.get("motions"))
        out.append({"fruit_id": r.get("fruit_id"), "leaf_id": r.get("leaf_id"),
                    "status": "ok" if moved else str(r.get("outcome", "")).split(":")[0],
                    "action": r["motions"][0] if moved else None})
        if moved:
            return out
    # no fruit moved: an episode that ended on a plan (aborted at the grasp,
    # or plan only) has it as its last plan.json
    try:
        plan = json.loads((Path(run_dir) / "plan.json").read_text())
    except (OSError, ValueError):
        return out or None
    t = plan.get("target") if isinstance(plan, dict) else None
    if isinstance(t, dict) and plan.get("status") == "ok" and plan.get("action"):
        out.append({"fruit_id": t.get("fruit_id"), "leaf_id": t.get("leaf_id"),
                    "status": "ok", "action": plan["action"]})
    return out or None


def SameFirstPlans(replayed: list[dict], run: list[dict]) -> bool:
    """Do the replay's fruit-by-fruit plans on view 0 match the run's (the
    same fruits and leaves in the same order, the same first motion)?"""
    def key(r):
        return (r.get("fruit_id"), r.get("leaf_id"), r.get("status") == "ok", r.get("action"))
    return [key(r) for r in replayed] == [key(r) for r in run]
