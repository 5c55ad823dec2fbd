#!/usr/bin/env python3
"""The digital twin's pace while it holds the leaf: CPU seconds per
simulated second and simulated s per wall s, the twin's settings before
and after the pace work side by side (alternating runs, medians).

    python scripts/bench_twin.py --out bench_twin.json
    python scripts/bench_twin.py --out bench_twin.json --repeats 5 --duration 2
    python scripts/bench_twin.py --out episodes.json --episodes --compare_code /tmp/old

The benchmark is ``lmap_drake.studies.twin_benchmark`` (what is timed, the
scripted pull that stands in for the ur_rtde client's servo stream).
"""
import argparse
import json
import sys
from pathlib import Path

from lmap_drake.errors import OneLineArgumentParser
from lmap_drake.studies.twin_benchmark import VARIANTS, BenchTwinEpisodes, BenchTwinHeld


def main(argv=None) -> None:
    p = OneLineArgumentParser(description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--duration", type=float, default=2.0, help="the pull's simulated s")
    p.add_argument("--variants", default="before,after",
                   help=f"comma-separated, of {', '.join(VARIANTS)}")
    p.add_argument("--episodes", action="store_true",
                   help="whole episodes with the real ur_rtde client against `lmap-drake twin "
                        "--rate 1` instead (the twin's own pace per phase)")
    p.add_argument("--compare_code", default="",
                   help="--episodes: also run the twin of this checkout (its folder holding "
                        "lmap_drake/), alternating with this one")
    a = p.parse_args(argv)
    if a.episodes:
        if a.compare_code and not (Path(a.compare_code) / "lmap_drake").is_dir():
            p.error(f"--compare_code: no lmap_drake/ in {a.compare_code}")
        codes = {"this": ""} | ({"compare": a.compare_code} if a.compare_code else {})
        result = BenchTwinEpisodes(codes, a.repeats)
        with open(a.out, "w") as f:
            json.dump(result, f, indent=2)
        print(json.dumps(result["summary"], indent=2))
        return
    names = [v.strip() for v in a.variants.split(",") if v.strip()]
    unknown = [v for v in names if v not in VARIANTS]
    if unknown or not names:
        p.error(f"--variants: unknown {unknown}; choose from {', '.join(VARIANTS)}")
    if a.repeats < 1 or not 0 < a.duration <= 10:
        p.error("--repeats must be >= 1 and --duration in (0, 10] s")
    result = BenchTwinHeld({v: VARIANTS[v] for v in names}, a.repeats, a.duration)
    with open(a.out, "w") as f:
        json.dump(result, f, indent=2)
    print(json.dumps(result["summary"], indent=2))


if __name__ == "__main__":
    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="bench_twin.py", strip_debug=True))
