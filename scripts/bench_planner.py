#!/usr/bin/env python3
"""Per-stage seconds of the LMAP planner on the default scenario, named as
in the paper's Table IV.

    python scripts/bench_planner.py --out bench_planner.json [--shapes ssc|oracle]

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
from lmap_drake.planning.lmap import PlanLmap, PlanningContext
from lmap_drake.planning.robot_model import RobotModel
from lmap_drake.plants.simworld import OracleSceneEstimate, PlantWorldSim
from lmap_drake.scenario import LoadScenario


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True)
    p.add_argument("--scenario_name", default="Defaults")
    p.add_argument("--shapes", choices=["ssc", "oracle"], default="ssc")
    a = p.parse_args()
    s = LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name=a.scenario_name)
    world = PlantWorldSim(s)
    world.Hold(0.3)
    im = world.Images()
    t0 = time.perf_counter()
    sem = SemanticSceneFromImages(im["rgb_image"], im["depth_image"], im["label_image"],
                                  s.cameras["camera0"], s.perception)
    t_seg = time.perf_counter() - t0
    t0 = time.perf_counter()
    if a.shapes == "oracle":
        scene = OracleSceneEstimate(world, sem)
    else:
        from lmap_drake.shape.completion import CompleteScene
        from lmap_drake.shape.deepsdf import LoadDecoder
        from lmap_drake.shape.ssc import SscParams
        decoder, mean, _ = LoadDecoder(s.shape.weights_file)
        scene = CompleteScene(sem, decoder, mean, SscParams.FromConfig(s.shape))
    t_shape = time.perf_counter() - t0
    robot = RobotModel(s.robot.X_WB.GetDeterministicValue())
    ctx = PlanningContext(scene, s.cameras["camera0"].X_PB.GetDeterministicValue().GetAsMatrix4(),
                          robot, np.asarray(s.robot.initial_q))
    r = PlanLmap(ctx, s.planner, s.deformation, lambda m: print(f"[bench] {m}", flush=True))
    out = {k: r.timings.get(k) for k in ("generation_collision_s", "deformation_s",
                                         "visibility_s", "total_s")}
    out.update(num_candidates=len(r.candidates),
               num_feasible=sum(c.feasible for c in r.candidates),
               status=r.status, message=r.message,
               chosen=r.chosen.Row() if r.chosen else None,
               segmentation_s=t_seg, shape_completion_s=t_shape, shapes=a.shapes,
               rejections=dict(Counter(c.reason.split(" (")[0] or "feasible"
                                       for c in r.candidates)))
    with open(a.out, "w") as f:
        json.dump(out, f, indent=2)
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    import sys

    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="bench_planner.py", strip_debug=True))  # one-line errors; --debug
