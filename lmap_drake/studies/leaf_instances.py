"""How well leaf instances match the true leaves on greenhouse views
(``scripts/eval_leaf_instances.py``).

    python scripts/make_suite.py --greenhouse --random 3 --seed 57 --out out/gh57.yaml
    python scripts/eval_leaf_instances.py --render out/leafviews \
        --scenario_file diagrams/greenhouse_suite.yaml out/gh57.yaml
    python scripts/eval_leaf_instances.py --views out/leafviews --out out/leaf_instances.json

Rendering (``RenderViews``) writes each scenario's camera0 view (colour,
depth with the scenario's camera noise, render labels, intrinsics) as
``<dir>/<scenario>.npz``, so that the instance step can be measured and
changed without rendering again. ``EvalLeafInstances`` scores, per view,
two class maps — the truth (isolates the instance step) and ``segnet``'s —
and two instance steps on each:

- ``image``: the segmenter's pixel instances
  (``perception.segmentation.InstancesFromComponents``);
- ``points``: the leaf instances the planner gets
  (``perception.leaf_instances.PointLeafInstances``: DBSCAN, touching,
  necked and oversized leaves split), painted back on the pixels they came
  from; pixels the point pipeline drops (flying pixels, outliers, DBSCAN
  noise: mostly leaves seen edge-on) count as missed;
- ``points_kept``: the same with the dropped pixels left out (the grouping
  alone).

Scores (``perception.leaf_instances.LeafInstanceScores``): per true leaf
with at least ``min_pixels`` visible, the best IoU of any instance;
``matched_fraction`` (best IoU >= 0.5), ``mean_best_iou``,
``merges_per_view`` (instances holding half or more of two true leaves)
and ``splits_per_view`` (true leaves of which two instances hold a fifth
or more each).
"""
from __future__ import annotations

import dataclasses as dc
import json
import sys
import time
from pathlib import Path

import numpy as np

from lmap_drake.labels import LEAF, DecodeLabels, LeafBoundaryMask, NeighbourClassMap
from lmap_drake.perception.leaf_instances import (LeafInstanceScores, PointLeafInstances,
                                                  SummariseLeafInstances)
from lmap_drake.perception.points import Intrinsics
from lmap_drake.perception.segmentation import (InstancesFromComponents, MakeSegmenter,
                                                TruthClassMap)
from lmap_drake.scenario import LoadScenario, RawYaml

CLASS_MAPS = ("truth", "segnet")
STEPS = ("image", "points", "points_kept")


def _names(path: Path) -> list[str]:
    return [k for k in (RawYaml(Path(path).read_text()) or {}) if not str(k).startswith("_")]


def RenderViews(out_dir, scenario_files: list, names: list | None = None, log=print) -> list:
    """camera0's view of every scenario of ``scenario_files`` (or only
    ``names``) as ``out_dir/<name>.npz`` (rgb, depth, label, K = [width,
    height, fx, fy, cx, cy], scenario file); views already there are kept.
    Returns the paths."""
    from lmap_drake.plants.plant_station import RenderStill
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for f in scenario_files:
        for name in names or _names(f):
            path = out_dir / f"{name}.npz"
            paths.append(path)
            if path.exists():
                continue
            t0 = time.time()
            s = LoadScenario(filename=Path(f), scenario_name=name)
            rgb, depth, label = RenderStill(s)
            K = Intrinsics.FromCameraConfig(s.cameras["camera0"])
            tmp = path.with_name(path.stem + ".partial.npz")
            np.savez_compressed(tmp, rgb=rgb[..., :3], depth=depth, label=label,
                                K=np.array([K.width, K.height, K.fx, K.fy, K.cx, K.cy]),
                                scenario_file=str(f))
            tmp.replace(path)          # an interrupted render leaves no complete-looking view
            log(f"{name}: rendered in {time.time() - t0:.1f} s")
    return paths


def LoadView(path) -> dict:
    """A view written by ``RenderViews``: rgb, depth, label, K (Intrinsics)."""
    z = np.load(path)
    k = z["K"]
    return {"rgb": z["rgb"], "depth": z["depth"], "label": z["label"],
            "K": Intrinsics(int(k[0]), int(k[1]), *map(float, k[2:]))}


def ViewLeafInstances(view: dict, class_map: np.ndarray, perception,
                      baseline: bool = False, boundary: np.ndarray | None = None) -> dict:
    """{step: HxW leaf instance map (-1 = none)} of ``class_map`` on
    ``view`` for each instance step of ``STEPS``; ``baseline``: as before
    issue 57 (no neck cuts, sizes split without checking their spread);
    ``boundary``: the segmenter's leaf boundary (both steps cut along it)."""
    leaf = class_map == LEAF
    image = np.where(leaf, InstancesFromComponents(class_map, view["depth"],
                                                   leaf_neck_ratio=0.0 if baseline else 0.5,
                                                   leaf_boundary=boundary), -1)
    points = PointLeafInstances(class_map, view["depth"], view["K"], perception,
                                check_spread=not baseline, neck_ratio=0.0 if baseline else 0.5,
                                boundary=boundary)
    return {"image": image, "points": points}


def EvalLeafInstances(out, views: list, class_maps=CLASS_MAPS, min_pixels: int = 200,
                      baseline: bool = False, log=print, scenario_text: str = "") -> dict:
    """Scores the leaf instances of every view file (``RenderViews``) for
    each class map and instance step (``baseline``: the steps as before
    issue 57, ``ViewLeafInstances``); writes ``out`` (JSON: ``{class map:
    {step: summary, "views": {name: {step: row}}}}``) and returns it.
    ``scenario_text``: YAML overrides of the default scenario (its
    perception section is used: segnet weights, ``leaf_boundaries``)."""
    perception = LoadScenario(scenario_text=scenario_text).perception
    seg = None
    res = {c: {"views": {}} for c in class_maps}
    rows = {(c, s): [] for c in class_maps for s in STEPS}
    for path in views:
        path = Path(path)
        v = LoadView(path)
        cls_t, inst_t = DecodeLabels(v["label"])
        truth_leaf = np.where(cls_t == LEAF, inst_t, -1)
        ignore = NeighbourClassMap(v["label"]) != 0
        for c in class_maps:
            if c == "truth":
                cmap = TruthClassMap(v["label"])
                boundary = LeafBoundaryMask(truth_leaf)
            else:
                if seg is None:
                    seg = MakeSegmenter(dc.replace(perception, segmenter=c), v["K"])
                out_seg = seg.Segment(v["rgb"], v["depth"])
                cmap, boundary = out_seg.class_map, out_seg.leaf_boundary
            t0 = time.time()
            maps = ViewLeafInstances(v, cmap, perception, baseline,
                                     boundary if perception.leaf_boundaries and not baseline
                                     else None)
            row = {}
            dropped = (cmap == LEAF) & (maps["points"] < 0)
            for s in STEPS:
                m, ign = maps.get(s, maps["points"]), ignore | (dropped if s == "points_kept"
                                                                else False)
                row[s] = LeafInstanceScores(m, truth_leaf, min_pixels, ign)
                rows[(c, s)].append(row[s])
            row["seconds"] = round(time.time() - t0, 2)
            res[c]["views"][path.stem] = row
            log(f"{path.stem:28s} {c:7s} " + "  ".join(
                f"{s}: matched {row[s]['matched']}/{row[s]['leaves']} "
                f"merges {row[s]['merges']} splits {row[s]['splits']}" for s in STEPS[:2]))
    for c in class_maps:
        for s in STEPS:
            res[c][s] = SummariseLeafInstances(rows[(c, s)])
    res["_meta"] = {"views": [str(p) for p in views], "min_pixels": min_pixels,
                   "baseline": baseline, "scenario_text": scenario_text}
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".partial")
    tmp.write_text(json.dumps(res, indent=2))
    tmp.replace(out)
    for c in class_maps:
        for s in STEPS:
            print(f"{c:7s} {s:7s} {json.dumps(res[c][s])}", file=sys.stdout)
    return res
