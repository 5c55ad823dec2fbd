"""Segmentation IoU per backend and scenario against the simulator's labels.

    python scripts/eval_segmentation.py --out out/seg.json
    python scripts/eval_segmentation.py --scenario_file diagrams/default.yaml \
        --scenario_names Defaults OneOfEverything --backends color_depth label --out seg.json
    python scripts/eval_segmentation.py --scenarios 30 --seed 21 --out seg_random.json

Images come from the scenario's camera: the noisy L515-like model by default
(``--scenario_text "{camera_noise: {enabled: false}}"`` for perfect images).
``--scenarios N --seed S`` evaluates ``RandomSuite(N, S)`` instead of a file.

Default scenarios: every scenario in diagrams/suite.yaml if that file exists,
otherwise Defaults and OneOfEverything from diagrams/default.yaml.

Writes JSON: ``{backend: {"mean": {"fruit_iou", "leaf_iou", "branch_iou"},
"mean_non_green": {...}, "mean_green": {...}, "scenarios": {name: {...}}}}``.
IoU is over pixels; the robot counts as background. A class absent from both
the truth and the prediction has IoU null and is left out of the means.
``fruit_color`` (red / orange / yellow / green, from the rendered truth
pixels' hue) lets green peppers be reported separately. Per scenario,
``fruit_instances`` lists the backend's fruit instances of 50 pixels or
more with the truth fractions of their pixels (fruit / branch / leaf;
``FruitInstanceTruth``); ``phantoms`` counts those mostly not fruit (a
side shoot or stalk taken for a fruit: the planner would complete and
reveal a fruit that is not there), summed in each backend's
``instances``. Multi-fruit plants:

    python scripts/eval_segmentation.py --scenario_file diagrams/multi_suite.yaml \
        --settle 0.3 --backends segnet --out out/seg_multi.json
"""
from __future__ import annotations

import dataclasses as dc
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from lmap_drake.paths import REPO_ROOT as REPO
from lmap_drake.perception.points import Intrinsics
from lmap_drake.perception.segmentation import (ClassIou, FruitInstanceTruth, MakeSegmenter,
                                                RgbToHsv, TruthClassMap)
from lmap_drake.plants.suite import RandomSuite, SuiteYaml
from lmap_drake.plants.plant_station import RenderStill
from lmap_drake.scenario import LoadScenario, RawYaml
from lmap_drake.station.camera_noise import CameraProfile

CLASSES = (("fruit_iou", 3), ("leaf_iou", 2), ("branch_iou", 1))


def DefaultScenarios() -> tuple[Path, list[str]]:
    """The default scenario file and names ([] = every scenario in it)."""
    suite = REPO / "diagrams" / "suite.yaml"
    if suite.exists():
        return suite, []  # [] = every scenario in the file
    return REPO / "diagrams" / "default.yaml", ["Defaults", "OneOfEverything"]


def _scenario_names(path: Path) -> list[str]:
    return [k for k in (RawYaml(path.read_text()) or {}) if not str(k).startswith("_")]


def _fruit_color(rgb: np.ndarray, truth: np.ndarray) -> str | None:
    m = truth == 3
    if m.sum() == 0:
        return None
    h = RgbToHsv(rgb[..., :3])[..., 0][m]
    hue = float(np.degrees(np.angle(np.mean(np.exp(1j * np.radians(h))))) % 360)
    if hue >= 330 or hue < 15:
        return "red"
    if hue < 40:
        return "orange"
    if hue < 70:
        return "yellow"
    return "green"


def _mean(rows: list[dict]) -> dict:
    out = {}
    for key, _ in CLASSES:
        vals = [r[key] for r in rows if r.get(key) is not None]
        out[key] = float(np.mean(vals)) if vals else None
        out[key.replace("_iou", "_n")] = len(vals)
    return out


def Evaluate(scenario_file: Path, names: list[str], backends: list[str],
             scenario_text: str = "{}", settle: float = 0.0, log=print) -> dict:
    names = names or _scenario_names(scenario_file)
    results = {b: {"scenarios": {}} for b in backends}
    for name in tqdm(names, desc="eval_segmentation", unit="scene", file=sys.stderr):
        s = LoadScenario(filename=scenario_file, scenario_name=name, scenario_text=scenario_text)
        t0 = time.time()
        rgb, depth, label = RenderStill(s, settle)
        truth = TruthClassMap(label)
        color = _fruit_color(rgb, truth)
        K = Intrinsics.FromCameraConfig(s.cameras["camera0"])
        for backend in backends:
            cfg = dc.replace(s.perception, segmenter=backend)
            row = {"fruit_color": color,
                   "truth_pixels": {k.replace("_iou", ""): int((truth == c).sum())
                                    for k, c in CLASSES}}
            try:
                t1 = time.time()
                seg = MakeSegmenter(cfg, K).Segment(rgb, depth, label)
                row["seconds"] = round(time.time() - t1, 3)
                for key, c in CLASSES:
                    v = ClassIou(seg.class_map, truth, c)
                    row[key] = None if math.isnan(v) else round(v, 4)
                row["flags"] = seg.flags
                row["fruit_instances"] = FruitInstanceTruth(seg, truth)
                row["phantoms"] = sum(r["fruit"] < 0.5 for r in row["fruit_instances"])
            except Exception as err:  # e.g. grounded_sam without weights
                row["error"] = f"{type(err).__name__}: {err}"
            results[backend]["scenarios"][name] = row
            log(f"{name:24s} {backend:12s} " + (row.get("error") or " ".join(
                f"{k}={row[k]}" for k, _ in CLASSES)) + f"  fruit={color}")
        log(f"  ({time.time() - t0:.1f} s)")
    for backend, res in results.items():
        rows = [r for r in res["scenarios"].values() if "error" not in r]
        res["mean"] = {k: v for k, v in _mean(rows).items() if k.endswith("_iou")}
        res["counts"] = {k: v for k, v in _mean(rows).items() if k.endswith("_n")}
        res["mean_non_green"] = _mean([r for r in rows if r["fruit_color"] != "green"])
        res["mean_green"] = _mean([r for r in rows if r["fruit_color"] == "green"])
        res["instances"] = {"fruit_instances": sum(len(r["fruit_instances"]) for r in rows),
                            "phantoms": sum(r["phantoms"] for r in rows)}
    return results


def EvalSegmentation(out, scenario_file: Path | None = None, scenario_names: list | None = None,
                     backends: list[str] = ("segnet", "color_depth", "label"), scenarios: int = 0,
                     seed: int = 0, scenario_text: str = "{}", settle: float = 0.0) -> dict:
    """``Evaluate`` on ``scenario_file`` (default: ``DefaultScenarios``) or,
    with ``scenarios`` > 0, on ``RandomSuite(scenarios, seed)`` (written
    beside ``out`` as ``.suite.yaml``); writes ``out`` (JSON, with
    ``_meta``), prints one line per backend and returns the result."""
    file_default, names_default = DefaultScenarios()
    backends = list(backends)
    file = scenario_file or file_default
    if scenarios:
        file = Path(out).with_suffix(".suite.yaml")
        file.parent.mkdir(parents=True, exist_ok=True)
        file.write_text(SuiteYaml(RandomSuite(scenarios, seed),
                                  f"# RandomSuite({scenarios}, {seed})"))
    if scenario_names is not None:
        names = scenario_names
    else:
        names = names_default if (scenario_file is None and not scenarios) else []
    res = Evaluate(file, names, backends, scenario_text, settle)
    res["_meta"] = {"camera": CameraProfile(LoadScenario(scenario_text=scenario_text)
                                            .camera_noise),
                    "scenario_file": str(file),
                    "scenario_text": scenario_text, "settle": settle}
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    Path(out).write_text(json.dumps(res, indent=2))
    for b in backends:
        g, o = res[b]["mean_green"], res[b]["mean_non_green"]
        print(f"{b:12s} mean {res[b]['mean']}  fruit IoU green {g['fruit_iou']} "
              f"(n={g['fruit_n']}), others {o['fruit_iou']} (n={o['fruit_n']}); phantom fruit "
              f"instances {res[b]['instances']['phantoms']} of "
              f"{res[b]['instances']['fruit_instances']}")
    return res
