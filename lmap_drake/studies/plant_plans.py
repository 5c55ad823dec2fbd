"""What a multi-fruit episode would try for each fruit of a plant if each
were first in line, planned from the plant's first view without moving
anything (behind ``scripts/plan_plant.py``).

The plant settles, camera0 is segmented (``perception.segmenter``), the
plant is completed (``CompletePlant``), and for every fruit instance the
planner runs as ``PlantPlanning`` would (``PlanTarget``: each occluding leaf,
the rest of the plant as obstacles).
"""
from __future__ import annotations

import json
import re
import time
from collections import Counter
from pathlib import Path

import numpy as np

from lmap_drake.evaluation.run_eval import SuiteEntries
from lmap_drake.perception.observe import SemanticSceneFromImages
from lmap_drake.planning.robot_model import RobotModel
from lmap_drake.planning.targets import FruitOrder, PlanTarget
from lmap_drake.plants.plant_sim import PlantWorldSim
from lmap_drake.scenario import LoadScenario
from lmap_drake.shape.completion import CompletePlant
from lmap_drake.shape.deepsdf import LoadDecoder
from lmap_drake.systems.planning import ImageTangents


def RejectionReasons(plan) -> dict:
    """reason -> count over a plan's candidates (numbers replaced by #;
    "feasible" for the feasible ones)."""
    return dict(Counter(re.sub(r"\d[\d.e+-]*", "#", c.reason.split(" (")[0]) or "feasible"
                        for c in plan.candidates))


def PlanScene(s, quiet: bool = True) -> dict:
    """Every fruit's target plan from the settled plant's first view."""
    world = PlantWorldSim(s)
    world.Hold(0.3)
    im = world.Images()
    sem = SemanticSceneFromImages(im["rgb_image"], im["depth_image"], im["label_image"],
                                  s.cameras["camera0"], s.perception)
    decoder, mean, _ = LoadDecoder(s.shape.weights_file)
    t0 = time.perf_counter()
    plant = CompletePlant(sem, decoder, mean, s.shape.ssc, "ssc",
                          s.shape.free_space_voxel, s.shape.branch,
                          leaf_split_angle_deg=s.shape.leaf_split_angle_deg,
                          min_fruit_points=s.shape.min_fruit_points)
    t_shape = time.perf_counter() - t0
    X_WC = s.cameras["camera0"].X_PB.GetDeterministicValue().GetAsMatrix4()
    tan = ImageTangents(s)
    robot = RobotModel(s.robot.X_WB.GetDeterministicValue())
    order, occ = FruitOrder(plant, X_WC, s.planner, tan)
    gt = world.model.fruits if hasattr(world.model, "fruits") else []
    fruits = []
    for k, f in enumerate(plant.fruits):
        row = {"estimate": k, "center_W": np.round(f.center_W, 3).tolist(),
               "visible_predicted": round(occ[k]["visible"], 3),
               "occluders": occ[k]["leaves"], "in_order": k in order}
        if len(gt):
            d = [np.linalg.norm(np.asarray(g.center_W) - f.center_W) for g in gt]
            i = int(np.argmin(d))
            row.update(gt_fruit=i, gt_distance_cm=round(100 * d[i], 1),
                       gt_visibility=round(world.Visibility(fruit=i), 3))
        t0 = time.perf_counter()
        t = PlanTarget(plant, k, X_WC, robot, np.asarray(s.robot.initial_q), s.planner,
                       s.deformation, tan, occluders=occ[k])
        row.update(plan_s=round(time.perf_counter() - t0, 2), leaf_id=t.leaf_id, why=t.why,
                   options=[{"leaf_id": j, "status": p.status,
                             "predicted_visibility": (None if p.chosen is None or not p.seen_max
                                                      else round(p.chosen.seen / p.seen_max, 3)),
                             "chosen": p.chosen.Row() if p.chosen else None,
                             "reasons": RejectionReasons(p), "message": p.message}
                            for j, p in t.options])
        if not quiet:
            print(json.dumps({k2: v for k2, v in row.items() if k2 != "options"}), flush=True)
            for o in row["options"]:
                print("   ", o["leaf_id"], o["status"], o["predicted_visibility"],
                      o["reasons"], flush=True)
        fruits.append(row)
    return {"shape_completion_s": round(t_shape, 2), "order": order, "fruits": fruits}


def PlanPlants(scenario_file: str, out: str | Path, scenario_names: list[str] | tuple = (),
               scenario_text: str = "") -> dict:
    """``PlanScene`` on the named scenes of a scenario file (default: every
    scene), ``scenario_text`` overriding each; the JSON rewritten to ``out``
    after every scene."""
    names = list(scenario_names) or list(SuiteEntries(Path(scenario_file).read_text()))
    result = {}
    for name in names:
        print(f"[plan_plant] {name}", flush=True)
        s = LoadScenario(filename=scenario_file, scenario_name=name,
                         scenario_text=scenario_text or "{}")
        result[name] = PlanScene(s, quiet=False)
        Path(out).write_text(json.dumps(result, indent=1))
    return result
