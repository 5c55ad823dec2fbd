"""Per-stage seconds of the LMAP planner, named as in the paper's Table IV
(behind ``scripts/bench_planner.py``): the plant settles, camera0 is
segmented, the scene is completed (SSC with the trained DeepSDF, or the
simulator's exact fruit and branch with ``shapes="oracle"``), then the
planner runs the paper's 15 grasps x 14 directions x 4 distances.
"""
from __future__ import annotations

import json
import time
from collections import Counter
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from tqdm import tqdm

from lmap_drake.evaluation.run_eval import SuiteEntries
from lmap_drake.parallel import DefaultWorkers
from lmap_drake.paths import DEFAULT_SCENARIO_FILE
from lmap_drake.perception.observe import SemanticSceneFromImages
from lmap_drake.planning.context import PlanningContext
from lmap_drake.planning.lmap import PlanLmap
from lmap_drake.planning.result import PlanResult
from lmap_drake.planning.robot_model import RobotModel
from lmap_drake.planning.targets import FruitOrder, PlanTarget
from lmap_drake.plants.plant_sim import PlantWorldSim
from lmap_drake.plants.scripted import OracleSceneEstimate
from lmap_drake.scenario import LoadScenario
from lmap_drake.shape.completion import CompletePlant, CompleteScene
from lmap_drake.shape.deepsdf import LoadDecoder
from lmap_drake.studies.plant_plans import RejectionReasons
from lmap_drake.systems.planning import ImageTangents, PlantPlanning

STAGES = ("generation_collision_s", "deformation_s", "visibility_s", "total_s")


def _FirstView(s):
    """(world, SemanticScene, segmentation seconds): the scenario's plant
    settled 0.3 s and camera0 segmented (``perception.segmenter``)."""
    world = PlantWorldSim(s)
    world.Hold(0.3)
    im = world.Images()
    t0 = time.perf_counter()
    sem = SemanticSceneFromImages(im["rgb_image"], im["depth_image"], im["label_image"],
                                  s.cameras["camera0"], s.perception)
    return world, sem, time.perf_counter() - t0


def BenchScene(s, shapes: str, quiet: bool = False) -> dict:
    """Settles the scenario's plant, segments camera0, completes the scene,
    plans; per-stage seconds and the outcome."""
    world, sem, t_seg = _FirstView(s)
    t0 = time.perf_counter()
    if shapes == "oracle":
        scene = OracleSceneEstimate(world, sem)
    else:
        decoder, mean, _ = LoadDecoder(s.shape.weights_file)
        scene = CompleteScene(sem, decoder, mean, s.shape.ssc)
    t_shape = time.perf_counter() - t0
    robot = RobotModel(s.robot.X_WB.GetDeterministicValue())
    ctx = PlanningContext(scene, s.cameras["camera0"].X_PB.GetDeterministicValue().GetAsMatrix4(),
                          robot, np.asarray(s.robot.initial_q),
                          fruit_shapes=s.planner.fruit_shapes)
    say = (lambda m: None) if quiet else (lambda m: print(f"[bench] {m}", flush=True))
    r = PlanLmap(ctx, s.planner, s.deformation, say)
    out = {k: r.timings.get(k) for k in STAGES}
    out.update(num_candidates=len(r.candidates),
               num_feasible=sum(c.feasible for c in r.candidates),
               status=r.status, message=r.message,
               chosen=r.chosen.Row() if r.chosen else None,
               segmentation_s=t_seg, shape_completion_s=t_shape, shapes=shapes,
               rejections=dict(Counter(c.reason.split(" (")[0] or "feasible"
                                       for c in r.candidates)))
    return out


def BenchDefault(scenario_name: str = "Defaults", shapes: str = "ssc") -> dict:
    """``BenchScene`` on a scenario of ``diagrams/default.yaml``."""
    s = LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name=scenario_name)
    return BenchScene(s, shapes)


def BenchSuite(suite: str, shapes: str = "ssc") -> dict:
    """``BenchScene`` once in every scene of a suite YAML: per-scene results,
    the median of each stage and the longest total."""
    names = list(SuiteEntries(Path(suite).read_text()))
    scenes = {}
    for name in tqdm(names, desc="planning", unit="scene"):
        scenes[name] = BenchScene(LoadScenario(filename=suite, scenario_name=name),
                                  shapes, quiet=True)
    return {"suite": suite, "shapes": shapes, "num_scenes": len(scenes),
            "median": {k: float(np.median([r[k] for r in scenes.values()
                                           if r[k] is not None])) for k in STAGES},
            "max_total_s": max(r["total_s"] for r in scenes.values()),
            "scenes": scenes}


# ---- per-motion planning on a plant (``planner.targets: all``) ----------


def PlantPlanInputs(s) -> dict:
    """The settled plant's first view as the episode's ``PlantPlanning``
    sees it: camera0 segmented (``perception.segmenter``), the plant
    completed (``CompletePlant``, SSC with the trained DeepSDF). Returns
    {"plant", "segmentation_s", "shape_completion_s", "num_leaves",
    "num_fruits"}."""
    world, sem, t_seg = _FirstView(s)
    decoder, mean, _ = LoadDecoder(s.shape.weights_file)
    t0 = time.perf_counter()
    plant = CompletePlant(sem, decoder, mean, s.shape.ssc, "ssc", s.shape.free_space_voxel,
                          s.shape.branch, min_fruit_points=s.shape.min_fruit_points,
                          leaf_split_angle_deg=s.shape.leaf_split_angle_deg)
    t_shape = time.perf_counter() - t0
    ids = np.asarray(plant.semantic.leaf_instance)
    return {"plant": plant, "segmentation_s": round(t_seg, 3),
            "shape_completion_s": round(t_shape, 3),
            "num_leaves_model": len(getattr(world.model, "leaves", []) or []),
            "num_leaf_instances": int(len(np.unique(ids[ids >= 0]))),
            "num_fruits": len(plant.fruits)}


def _Clocks():
    return time.perf_counter(), time.process_time()


def PlanFirstMotion(s, plant, robot: RobotModel | None = None) -> tuple[PlanResult, dict]:
    """The episode's first plan on ``plant`` (``PlantPlanning``'s ``plan``
    port, a fresh context: nothing handled yet), timed, with the stages
    (the fruits' order and occluders, then per occluding leaf of the target
    the planner's own stages) timed by running the same functions again
    outside the system. Returns (the system's plan, the seconds)."""
    robot = robot or RobotModel(s.robot.X_WB.GetDeterministicValue())
    system = PlantPlanning(s, robot)
    ctx = system.CreateDefaultContext()
    system.GetInputPort("plant_estimate").FixValue(ctx, plant)
    system.GetInputPort("ur5.position").FixValue(ctx, np.asarray(s.robot.initial_q, float))
    system.GetInputPort("status").FixValue(ctx, SimpleNamespace(targets=[]))
    w0, c0 = _Clocks()
    plan = system.GetOutputPort("plan").Eval(ctx)
    w1, c1 = _Clocks()
    out = {"wall_s": w1 - w0, "cpu_s": c1 - c0}
    # the stages, outside the system (the same calls as PlantPlanning._Plan
    # on a first motion)
    X_WC = s.cameras["camera0"].X_PB.GetDeterministicValue().GetAsMatrix4()
    tan = ImageTangents(s)
    w0, c0 = _Clocks()
    order, occ = FruitOrder(plant, X_WC, s.planner, tan)
    w1, c1 = _Clocks()
    out["stages"] = {"fruit_order_wall_s": w1 - w0, "fruit_order_cpu_s": c1 - c0}
    if order:
        w0, c0 = _Clocks()
        t = PlanTarget(plant, order[0], X_WC, robot, np.asarray(s.robot.initial_q), s.planner,
                       s.deformation, tan, occluders=occ[order[0]])
        w1, c1 = _Clocks()
        out["stages"].update(plan_target_wall_s=w1 - w0, plan_target_cpu_s=c1 - c0)
        for k in STAGES:
            out["stages"][k] = sum(p.timings.get(k, 0.0) for _, p in t.options)
        out["stages"]["num_leaf_plans"] = len(t.options)
    return plan, out


def _PlanRecord(plan: PlanResult) -> dict:
    """What must not change when the planner gets faster: the status, the
    target and leaf, the chosen action, the candidates' verdicts."""
    tgt = plan.target or {}
    return {"status": plan.status, "message": plan.message,
            "fruit_id": tgt.get("fruit_id"), "leaf_id": tgt.get("leaf_id"),
            "chosen": None if plan.chosen is None else plan.chosen.Row(),
            "num_candidates": len(plan.candidates),
            "num_feasible": sum(c.feasible for c in plan.candidates),
            "options": tgt.get("options"),
            "rejections": RejectionReasons(plan)}


def _Rounded(x, digits: int = 8):
    """``x`` (a JSON-able record) with every float rounded to ``digits``
    significant digits: two runs of the same code in two processes gave
    ARAP energies 1e-10 apart (relative; ``gh_immature_partial``)."""
    if isinstance(x, float):
        return float(f"{x:.{digits}g}")
    if isinstance(x, dict):
        return {k: _Rounded(v, digits) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_Rounded(v, digits) for v in x]
    return x


def SamePlan(a: dict, b: dict) -> bool:
    """Whether two plan records (``_PlanRecord``) are the same plan: equal
    but for floats' digits beyond the 8th (``_Rounded``)."""
    return (json.dumps(_Rounded(a), sort_keys=True) == json.dumps(_Rounded(b), sort_keys=True))


def BenchPlantMotions(scenario_file: str, scenario_names: list[str], repeats: int = 3,
                      scenario_text: str = "", out: str | Path | None = None,
                      reference: dict | None = None) -> dict:
    """Per-motion planning seconds on plants (``PlanFirstMotion`` ``repeats``
    times per scene: median and every run, wall and CPU), with the plan's
    record (``_PlanRecord``; every repeat must give the same). ``reference``
    (an earlier result): each scene's record is compared with its own and
    the verdict written (``same_as_reference``). The JSON is rewritten to
    ``out`` after every scene (``complete`` false until the last)."""
    result = {"scenario_file": str(scenario_file), "scenario_text": scenario_text,
              "repeats": repeats, "threads": DefaultWorkers(), "complete": False,
              "scenes": {}}
    # every scene read first: a bad name or value stops the run before any plant is built
    scenarios = {name: LoadScenario(filename=scenario_file, scenario_name=name,
                                    scenario_text=scenario_text or "{}")
                 for name in scenario_names}
    for name, s in scenarios.items():
        inputs = PlantPlanInputs(s)
        runs, records = [], []
        for _ in range(repeats):
            plan, t = PlanFirstMotion(s, inputs["plant"])
            runs.append(t)
            records.append(_PlanRecord(plan))
        row = {k: v for k, v in inputs.items() if k != "plant"}
        row.update(
            planner_targets=s.planner.targets, segmenter=s.perception.segmenter,
            median_wall_s=round(float(np.median([r["wall_s"] for r in runs])), 3),
            median_cpu_s=round(float(np.median([r["cpu_s"] for r in runs])), 3),
            median_stages={k: round(float(np.median([r["stages"][k] for r in runs
                                                     if k in r["stages"]])), 3)
                           for k in runs[0]["stages"]},
            runs=[{"wall_s": round(r["wall_s"], 3), "cpu_s": round(r["cpu_s"], 3)}
                  for r in runs],
            repeats_agree=all(SamePlan(r, records[0]) for r in records),
            plan=records[0])
        if reference is not None and name in reference.get("scenes", {}):
            row["same_as_reference"] = SamePlan(reference["scenes"][name]["plan"], records[0])
        print(f"[bench_planner] {name}: {row['median_wall_s']} s wall, {row['median_cpu_s']} s "
              f"CPU per motion ({row['num_leaf_instances']} leaf instances, "
              f"{row['plan']['status']})", flush=True)
        result["scenes"][name] = row
        if out:
            Path(out).write_text(json.dumps(result, indent=1))
    rows = list(result["scenes"].values())
    result["max_median_wall_s"] = max(r["median_wall_s"] for r in rows)
    result["max_median_cpu_s"] = max(r["median_cpu_s"] for r in rows)
    result["complete"] = True
    if out:
        Path(out).write_text(json.dumps(result, indent=1))
    return result
