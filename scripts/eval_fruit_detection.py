"""Which fruits perception finds in a plant's first view, and at what
thresholds: every plant of the scenario files is rendered (camera0, arm at
its start pose), segmented (``perception.segmenter``, default segnet),
de-projected into 3D fruit instances for each DBSCAN ``min_points`` value,
and each instance matched to the true fruit meshes (an instance is on a
fruit when at least half its points lie within ``--on_fruit`` of that
fruit's surface; otherwise it is a phantom). For each (DBSCAN
``min_points``, smallest instance the planner takes) pair it counts the
instances kept, the true fruits seen and the phantoms.

    python scripts/eval_fruit_detection.py --scenario_file diagrams/multi_suite.yaml \\
        --out out/fruit_detection.json

The planner takes instances of ``shape.min_fruit_points`` (20) points or
more after DBSCAN with ``perception.dbscan_min_points`` (15): a fruit 5-12 %
visible can show as a sliver beside its leaf that segnet labels fruit but
that keeps few points (the defaults were 30 and 30 before this study).

Writes JSON: ``{"settings": [{"dbscan_min_points", "min_instance_points",
"instances", "fruits_seen", "phantoms", "fruits"}], "plants": {name:
{"fruits": N, "instances": {dbscan_min_points: [{"points", "fruit",
"on_fruit"}]}}}}``.
"""
from __future__ import annotations

import argparse
import dataclasses as dc
import json
import sys
from pathlib import Path

import numpy as np


def MatchInstances(points_W: np.ndarray, instance: np.ndarray, fruit_trees: list,
                   on_fruit: float = 0.006) -> list[dict]:
    """Every instance id >= 0 of ``points_W`` (N, 3) m: its point count, the
    true fruit whose surface its points are nearest (median distance;
    ``fruit_trees`` are KD-trees of surface samples, one per fruit) and the
    fraction of its points within ``on_fruit`` (m) of that surface."""
    points_W, instance = np.asarray(points_W, float), np.asarray(instance)
    out = []
    if not len(fruit_trees):
        return [{"points": int((instance == i).sum()), "fruit": None, "on_fruit": 0.0}
                for i in np.unique(instance[instance >= 0])]
    for i in np.unique(instance[instance >= 0]):
        P = points_W[instance == i]
        D = np.stack([t.query(P)[0] for t in fruit_trees])
        best = int(np.argmin(np.median(D, axis=1)))
        out.append({"points": int(len(P)), "fruit": best,
                    "on_fruit": round(float(np.mean(D[best] < on_fruit)), 3)})
    return out


def Summarize(plants: dict, dbscan_values: list[int], thresholds: list[int]) -> list[dict]:
    """Per (DBSCAN min_points, smallest instance) pair: instances kept, true
    fruits seen (by an instance mostly on them), phantoms, and all fruits."""
    rows = []
    for mp in dbscan_values:
        for thr in thresholds:
            inst = seen = phantoms = fruits = 0
            for plant in plants.values():
                fruits += plant["fruits"]
                kept = [r for r in plant["instances"][str(mp)] if r["points"] >= thr]
                inst += len(kept)
                real = {r["fruit"] for r in kept if r["on_fruit"] >= 0.5}
                seen += len(real)
                phantoms += sum(r["on_fruit"] < 0.5 for r in kept)
            rows.append({"dbscan_min_points": mp, "min_instance_points": thr,
                         "instances": inst, "fruits_seen": seen, "phantoms": phantoms,
                         "fruits": fruits})
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario_file", nargs="+", required=True, help="scenario YAML(s)")
    ap.add_argument("--scenario_names", nargs="*", help="only these scenarios")
    ap.add_argument("--dbscan_min_points", nargs="+", type=int, default=[30, 15, 8])
    ap.add_argument("--min_instance_points", nargs="+", type=int, default=[30, 20, 15, 10])
    ap.add_argument("--on_fruit", type=float, default=0.006,
                    help="m: a point within this of a fruit's surface is on it")
    ap.add_argument("--settle", type=float, default=0.3,
                    help="simulated seconds before rendering (the FEM leaves settle)")
    ap.add_argument("--out", required=True, help="output JSON file")
    args = ap.parse_args(argv)
    files = [Path(f) for f in args.scenario_file]
    for f in files:
        if not f.is_file():
            print(f"eval_fruit_detection: error: --scenario_file {f} does not exist",
                  file=sys.stderr)
            return 2
    if min(args.dbscan_min_points + args.min_instance_points) < 1 or args.on_fruit <= 0:
        print("eval_fruit_detection: error: --dbscan_min_points and --min_instance_points "
              "must be >= 1, --on_fruit > 0", file=sys.stderr)
        return 2
    from lmap_drake.shape.benchmark import SuiteScenarioNames
    jobs = [(f, n) for f in files for n in SuiteScenarioNames(f)
            if not args.scenario_names or n in args.scenario_names]
    if not jobs:
        print("eval_fruit_detection: error: no scenario selected", file=sys.stderr)
        return 2

    import trimesh
    from scipy.spatial import cKDTree
    from tqdm import tqdm

    from lmap_drake.perception.observe import SemanticSceneFromImages
    from lmap_drake.plants.plant_station import GetPlantModel, RenderStill
    from lmap_drake.scenario import LoadScenario

    plants = {}
    for f, name in tqdm(jobs, desc="eval_fruit_detection", unit="plant", file=sys.stderr):
        s = LoadScenario(filename=str(f), scenario_name=name, scenario_text=[])
        model = GetPlantModel(s)
        meshes = [fr.mesh_W for fr in getattr(model, "fruits", [])] or [model.fruit_mesh_W]
        trees = [cKDTree(trimesh.sample.sample_surface_even(m, 20000, seed=0)[0])
                 for m in meshes]
        rgb, depth, label = RenderStill(s, args.settle)
        row = {"fruits": len(meshes), "instances": {}}
        for mp in args.dbscan_min_points:
            cfg = dc.replace(s.perception, dbscan_min_points=mp)
            sem = SemanticSceneFromImages(rgb, depth, label, s.cameras["camera0"], cfg)
            row["instances"][str(mp)] = MatchInstances(sem.fruit_points_W, sem.fruit_instance,
                                                       trees, args.on_fruit)
        plants[name] = row
    settings = Summarize(plants, args.dbscan_min_points, args.min_instance_points)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(out.suffix + ".part")
    tmp.write_text(json.dumps({"settings": settings, "plants": plants}, indent=1))
    tmp.replace(out)
    for r in settings:
        print(f"DBSCAN min_points {r['dbscan_min_points']:3d}, instances >= "
              f"{r['min_instance_points']:3d} points: {r['fruits_seen']} of {r['fruits']} "
              f"fruits seen, {r['phantoms']} phantoms ({r['instances']} instances)")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
