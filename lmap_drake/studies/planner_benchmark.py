"""Per-stage seconds of the LMAP planner, named as in the paper's Table IV
(behind ``scripts/bench_planner.py``): the plant settles, camera0 is
segmented, the scene is completed (SSC with the trained DeepSDF, or the
simulator's exact fruit and branch with ``shapes="oracle"``), then the
planner runs the paper's 15 grasps x 14 directions x 4 distances.
"""
from __future__ import annotations

import time
from collections import Counter
from pathlib import Path

import numpy as np
from tqdm import tqdm

from lmap_drake.evaluation.run_eval import SuiteEntries
from lmap_drake.paths import DEFAULT_SCENARIO_FILE
from lmap_drake.perception.observe import SemanticSceneFromImages
from lmap_drake.planning.context import PlanningContext
from lmap_drake.planning.lmap import PlanLmap
from lmap_drake.planning.robot_model import RobotModel
from lmap_drake.plants.plant_sim import PlantWorldSim
from lmap_drake.plants.scripted import OracleSceneEstimate
from lmap_drake.scenario import LoadScenario
from lmap_drake.shape.completion import CompleteScene
from lmap_drake.shape.deepsdf import LoadDecoder

STAGES = ("generation_collision_s", "deformation_s", "visibility_s", "total_s")


def BenchScene(s, shapes: str, quiet: bool = False) -> dict:
    """Settles the scenario's plant, segments camera0, completes the scene,
    plans; per-stage seconds and the outcome."""
    world = PlantWorldSim(s)
    world.Hold(0.3)
    im = world.Images()
    t0 = time.perf_counter()
    sem = SemanticSceneFromImages(im["rgb_image"], im["depth_image"], im["label_image"],
                                  s.cameras["camera0"], s.perception)
    t_seg = time.perf_counter() - t0
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
