
from __future__ import annotations

import dataclasses as dc
import json
import sys
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree
from tqdm import tqdm

from lmap_drake.errors import InputError
from lmap_drake.perception.observe import SemanticSceneFromImages
from lmap_drake.plants.plant_station import GetPlantModel, RenderStill
from lmap_drake.scenario import LoadScenario
from lmap_drake.studies.shape_benchmark import SuiteScenarioNames


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


def EvalFruitDetection(scenario_file: list, out, scenario_names: list | None = None,
                       dbscan_min_points: list[int] = (30, 15, 8),
                       min_instance_points: list[int] = (30, 20, 15, 10),
                       on_fruit: float = 0.006, settle: float = 0.3) -> None:
    """Renders and segments every plant of the files ``scenario_file``
    (only ``scenario_names`` when given), matches the fruit instances per
    DBSCAN ``min_points`` value, writes ``out`` (JSON) and prints one line
    per setting. Raises InputError (nothing written) for a missing file,
    a threshold below 1, ``on_fruit`` <= 0 or no scenario selected."""
    files = [Path(f) for f in scenario_file]
    for f in files:
        if not f.is_file():
            raise InputError(f"--scenario_file {f} does not exist")
    dbscan_min_points, min_instance_points = list(dbscan_min_points), list(min_instance_points)
    if min(dbscan_min_points + min_instance_points) < 1 or on_fruit <= 0:
        raise InputError("--dbscan_min_points and --min_instance_points must be >= 1, "
                         "--on_fruit > 0")
    jobs = [(f, n) for f in files for n in SuiteScenarioNames(f)
            if not scenario_names or n in scenario_names]
    if not jobs:
        raise InputError("no scenario selected")

    plants = {}
    for f, name in tqdm(jobs, desc="eval_fruit_detection", unit="plant", file=sys.stderr):
        s = LoadScenario(filename=str(f), scenario_name=name, scenario_text=[])
        model = GetPlantModel(s)
        meshes = [fr.mesh_W for fr in getattr(model, "fruits", [])] or [model.fruit_mesh_W]
        trees = [cKDTree(trimesh.sample.sample_surface_even(m, 20000, seed=0)[0])
                 for m in meshes]
        rgb, depth, label = RenderStill(s, settle)
        row = {"fruits": len(meshes), "instances": {}}
        for mp in dbscan_min_points:
            cfg = dc.replace(s.perception, dbscan_min_points=mp)
            sem = SemanticSceneFromImages(rgb, depth, label, s.cameras["camera0"], cfg)
            row["instances"][str(mp)] = MatchInstances(sem.fruit_points_W, sem.fruit_instance,
                                                       trees, on_fruit)
        plants[name] = row
    settings = Summarize(plants, dbscan_min_points, min_instance_points)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(out.suffix + ".part")
    tmp.write_text(json.dumps({"settings": settings, "plants": plants}, indent=1))
    tmp.replace(out)
    for r in settings:
        print(f"DBSCAN min_points {r['dbscan_min_points']:3d}, instances >= "
              f"{r['min_instance_points']:3d} points: {r['fruits_seen']} of {r['fruits']} "
              f"fruits seen, {r['phantoms']} phantoms ({r['instances']} instances)")
    print(f"wrote {out}")
