#!/usr/bin/env python3
"""Per-stage seconds of the LMAP planner on the default scenario, named as
in the paper's Table IV.

    python scripts/bench_planner.py --out bench_planner.json [--shapes ssc|oracle]
    python scripts/bench_planner.py --suite diagrams/suite.yaml --out bench_suite.json
    python scripts/bench_planner.py --plants diagrams/greenhouse_suite.yaml \
        --plant gh_three_targets --scenario_text '{perception: {segmenter: label}}' \
        --repeats 3 --out bench_plants.json [--reference earlier.json]

The plant settles, camera0 is segmented (``perception.segmenter``), the
scene is completed (SSC with the trained DeepSDF, or ``--shapes oracle``:
the simulator's exact fruit and branch), then the planner runs the paper's
15 grasps x 14 directions x 4 distances. Writes
{"generation_collision_s", "deformation_s", "visibility_s", "total_s",
"num_candidates", "num_feasible", ...}. The benchmark is
``lmap_drake.studies.planner_benchmark``.

``--plants``: the planning of one motion on plants of several leaves and
fruits (``planner.targets: all``, as ``PlantPlanning`` plans an episode's
first motion), repeated: per scene the median wall and CPU seconds, the
stages (the fruits' order and occluders; per occluding leaf tried, the
planner's stages), the plan (status, target, leaf, chosen action,
rejections); ``--reference``: an earlier output whose plans must be the
same (``same_as_reference`` per scene). Run it single-threaded
(``LMAP_DRAKE_THREADS=1 OMP_NUM_THREADS=1``) for per-core figures.
"""
import argparse
import json
import sys
from pathlib import Path

from lmap_drake.errors import OneLineArgumentParser
from lmap_drake.evaluation.run_eval import SuiteEntries
from lmap_drake.studies.planner_benchmark import BenchDefault, BenchPlantMotions, BenchSuite


def main(argv=None) -> None:
    p = OneLineArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True)
    p.add_argument("--scenario_name", default="Defaults")
    p.add_argument("--suite", default="",
                   help="a suite YAML (e.g. diagrams/suite.yaml): plan once in every scene; "
                        "writes per-scene results and the median of each stage")
    p.add_argument("--shapes", choices=["ssc", "oracle"], default="ssc")
    p.add_argument("--plants", default="",
                   help="a scenario file of plants (e.g. diagrams/greenhouse_suite.yaml): "
                        "time the planning of a first motion (planner.targets: all)")
    p.add_argument("--plant", action="append", default=[],
                   help="--plants: scene(s) of the file (repeat; default: every scene)")
    p.add_argument("--scenario_text", default="", help="--plants: YAML override for every scene")
    p.add_argument("--repeats", type=int, default=3, help="--plants: plans per scene (>= 1)")
    p.add_argument("--reference", default="",
                   help="--plants: an earlier output; its plans must be the same")
    a = p.parse_args(argv)
    if a.plants:
        if not Path(a.plants).is_file():
            p.error(f"--plants {a.plants}: no such file")
        if a.repeats < 1:
            p.error(f"--repeats must be at least 1, got {a.repeats}")
        ref = None
        if a.reference:
            try:
                ref = json.loads(Path(a.reference).read_text())
            except (OSError, ValueError) as err:
                p.error(f"--reference {a.reference}: cannot read it as JSON ({err})")
        names = a.plant or list(SuiteEntries(Path(a.plants).read_text()))
        out = BenchPlantMotions(a.plants, names, a.repeats, a.scenario_text, a.out, ref)
        print(json.dumps({k: v for k, v in out.items() if k != "scenes"}, indent=2))
        if ref is not None and not all(r.get("same_as_reference", True)
                                       for r in out["scenes"].values()):
            print("plans differ from --reference", file=sys.stderr)
            return 1
        return 0
    out = BenchSuite(a.suite, a.shapes) if a.suite else BenchDefault(a.scenario_name, a.shapes)
    with open(a.out, "w") as f:
        json.dump(out, f, indent=2)
    print(json.dumps(out if not a.suite else {k: out[k] for k in
                                              ("median", "max_total_s", "num_scenes")},
                     indent=2))


if __name__ == "__main__":
    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="bench_planner.py", strip_debug=True))  # one-line errors; --debug
