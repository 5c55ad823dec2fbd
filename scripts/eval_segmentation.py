#!/usr/bin/env python
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

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
CLASSES = (("fruit_iou", 3), ("leaf_iou", 2), ("branch_iou", 1))


def _default_scenarios() -> tuple[Path, list[str]]:
    suite = REPO / "diagrams" / "suite.yaml"
    if suite.exists():
        return suite, []  # [] = every scenario in the file
    return REPO / "diagrams" / "default.yaml", ["Defaults", "OneOfEverything"]


def _scenario_names(path: Path) -> list[str]:
    from lmap_drake.scenario import _RawYaml
    return [k for k in (_RawYaml(path.read_text()) or {}) if not str(k).startswith("_")]


def _fruit_color(rgb: np.ndarray, truth: np.ndarray) -> str | None:
    from lmap_drake.perception.segmentation import RgbToHsv
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
    import dataclasses as dc

    from lmap_drake.perception.points import Intrinsics
    from lmap_drake.perception.segmentation import (ClassIou, FruitInstanceTruth, MakeSegmenter,
                                                    TruthClassMap)
    from lmap_drake.scenario import LoadScenario
    from lmap_drake.plants.plant_station import RenderStill
    names = names or _scenario_names(scenario_file)
    from tqdm import tqdm
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


def main(argv=None) -> int:
    file_default, names_default = _default_scenarios()
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="output JSON file")
    ap.add_argument("--scenario_file", type=Path, default=None,
                    help=f"scenario YAML (default {file_default.relative_to(REPO)})")
    ap.add_argument("--scenario_names", nargs="*", default=None,
                    help="scenario names (default: every scenario in suite.yaml, or "
                         "Defaults OneOfEverything in default.yaml)")
    ap.add_argument("--backends", nargs="+", default=["segnet", "color_depth", "label"])
    ap.add_argument("--scenarios", type=int, default=0,
                    help="evaluate RandomSuite(N, --seed) instead of a scenario file")
    ap.add_argument("--seed", type=int, default=0, help="RandomSuite seed")
    ap.add_argument("--scenario_text", default="{}", help="YAML overrides for every scenario")
    ap.add_argument("--settle", type=float, default=0.0,
                    help="simulated seconds before rendering (e.g. for a FEM leaf to settle)")
    args = ap.parse_args(argv)
    scenario_file = args.scenario_file or file_default
    if args.scenarios < 0:
        ap.error("--scenarios must be >= 0")
    if args.scenarios:
        from lmap_drake.plants.suite import RandomSuite, SuiteYaml
        scenario_file = Path(args.out).with_suffix(".suite.yaml")
        scenario_file.parent.mkdir(parents=True, exist_ok=True)
        scenario_file.write_text(SuiteYaml(RandomSuite(args.scenarios, args.seed),
                                           f"# RandomSuite({args.scenarios}, {args.seed})"))
    if args.scenario_names is not None:
        names = args.scenario_names
    else:
        names = names_default if (args.scenario_file is None and not args.scenarios) else []
    res = Evaluate(scenario_file, names, args.backends, args.scenario_text, args.settle)
    from lmap_drake.scenario import LoadScenario
    from lmap_drake.station.camera_noise import CameraProfile
    res["_meta"] = {"camera": CameraProfile(LoadScenario(scenario_text=args.scenario_text)
                                            .camera_noise),
                    "scenario_file": str(scenario_file),
                    "scenario_text": args.scenario_text, "settle": args.settle}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(res, indent=2))
    for b in args.backends:
        g, o = res[b]["mean_green"], res[b]["mean_non_green"]
        print(f"{b:12s} mean {res[b]['mean']}  fruit IoU green {g['fruit_iou']} "
              f"(n={g['fruit_n']}), others {o['fruit_iou']} (n={o['fruit_n']}); phantom fruit "
              f"instances {res[b]['instances']['phantoms']} of "
              f"{res[b]['instances']['fruit_instances']}")
    return 0


if __name__ == "__main__":
    import sys

    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="eval_segmentation.py", strip_debug=True))  # one-line errors; --debug
