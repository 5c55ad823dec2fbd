#!/usr/bin/env python
"""Calibrates the planner's ``max_energy_per_node`` (predicted ARAP energy
per deformable leaf node above which an action is rejected as a damage
risk) from simulated episodes.

    python scripts/calibrate_energy_cap.py --out cap.json out/eval_chain/episodes.jsonl [...]

The study is ``lmap_drake.studies.energy_cap`` (input records, output JSON,
how the shipped cap was found).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

from lmap_drake.errors import OneLineArgumentParser
from lmap_drake.studies.energy_cap import Calibrate, LoadRecords


def main(argv=None) -> int:
    ap = OneLineArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("records", nargs="+", help="episodes.jsonl / episode.json files")
    ap.add_argument("--out", required=True, help="JSON file to write")
    args = ap.parse_args(argv)
    try:
        res = Calibrate(LoadRecords(args.records))
    except (OSError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    Path(args.out).write_text(json.dumps(res, indent=2))
    print(json.dumps({k: v for k, v in res.items() if k != "rows"}, indent=2))
    return 0


if __name__ == "__main__":
    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="calibrate_energy_cap.py", strip_debug=True))  # one-line errors; --debug
