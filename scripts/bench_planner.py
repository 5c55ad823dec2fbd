#!/usr/bin/env python3
"""Per-stage seconds of the LMAP planner on the default scenario, named as
in the paper's Table IV.

    python scripts/bench_planner.py --out bench_planner.json [--shapes ssc|oracle]
    python scripts/bench_planner.py --suite diagrams/suite.yaml --out bench_suite.json

The plant settles, camera0 is segmented (``perception.segmenter``), the
scene is completed (SSC with the trained DeepSDF, or ``--shapes oracle``:
the simulator's exact fruit and branch), then the planner runs the paper's
15 grasps x 14 directions x 4 distances. Writes
{"generation_collision_s", "deformation_s", "visibility_s", "total_s",
"num_candidates", "num_feasible", ...}.
"""
import argparse
import json
import time
from collections import Counter

import numpy as np

from lmap_drake.paths import DEFAULT_SCENARIO_FILE
from lmap_drake.perception.observe import SemanticSceneFromImages
from lmap_drake.planning.context import PlanningContext
from lmap_drake.planning.lmap import PlanLmap
from lmap_drake.planning.robot_model import RobotModel
from lmap_drake.plants.plant_sim import PlantWorldSim
from lmap_drake.plants.scripted import OracleSceneEstimate
from lmap_drake.scenario import LoadScenario


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
        from lmap_drake.shape.completion import CompleteScene
        from lmap_drake.shape.deepsdf import LoadDecoder
        decoder, mean, _ = LoadDecoder(s.shape.weights_file)
        scene = CompleteScene(sem, decoder, mean, s.shape.ssc)
    t_shape = time.perf_counter() - t0
    robot = RobotModel(s.robot.X_WB.GetDeterministicValue())
    ctx = PlanningContext(scene, s.cameras["camera0"].X_PB.GetDeterministicValue().GetAsMatrix4(),
                          robot, np.asarray(s.robot.initial_q))
    say = (lambda m: None) if quiet else (lambda m: print(f"[bench] {m}", flush=True))
    r = PlanLmap(ctx, s.planner, s.deformation, say)
    out = {k: r.timings.get(k) for k in ("generation_collision_s", "deformation_s",
                                         "visibility_s", "total_s")}
    out.update(num_candidates=len(r.candidates),
               num_feasible=sum(c.feasible for c in r.candidates),
               status=r.status, message=r.message,
               chosen=r.chosen.Row() if r.chosen else None,
               segmentation_s=t_seg, shape_completion_s=t_shape, shapes=shapes,
               rejections=dict(Counter(c.reason.split(" (")[0] or "feasible"
                                       for c in r.candidates)))
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True)
    p.add_argument("--scenario_name", default="Defaults")
    p.add_argument("--suite", default="",
                   help="a suite YAML (e.g. diagrams/suite.yaml): plan once in every scene; "
                        "writes per-scene results and the median of each stage")
    p.add_argument("--shapes", choices=["ssc", "oracle"], default="ssc")
    a = p.parse_args()
    if a.suite:
        from tqdm import tqdm

        from lmap_drake.evaluation.run_eval import SuiteEntries
        from pathlib import Path
        names = list(SuiteEntries(Path(a.suite).read_text()))
        scenes = {}
        for name in tqdm(names, desc="planning", unit="scene"):
            scenes[name] = BenchScene(LoadScenario(filename=a.suite, scenario_name=name),
                                      a.shapes, quiet=True)
        keys = ("generation_collision_s", "deformation_s", "visibility_s", "total_s")
        out = {"suite": a.suite, "shapes": a.shapes, "num_scenes": len(scenes),
               "median": {k: float(np.median([r[k] for r in scenes.values()
                                              if r[k] is not None])) for k in keys},
               "max_total_s": max(r["total_s"] for r in scenes.values()),
               "scenes": scenes}
    else:
        s = LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name=a.scenario_name)
        out = BenchScene(s, a.shapes)
    with open(a.out, "w") as f:
        json.dump(out, f, indent=2)
    print(json.dumps(out if not a.suite else {k: out[k] for k in
                                              ("median", "max_total_s", "num_scenes")},
                     indent=2))


if __name__ == "__main__":
    import sys

    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="bench_planner.py", strip_debug=True))  # one-line errors; --debug
