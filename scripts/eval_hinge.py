#!/usr/bin/env python
"""The hinge estimate against the true petiole attachment, per leaf instance.

    lmap-drake run --plan-only --scenario_file F --scenario_name N --output out/runs/N
    python scripts/eval_hinge.py --runs out/runs/* --out out/hinge.json

Each run folder must be a simulated run (its ground truth is read); view 0
is rebuilt with the run's own scenario (``--scenario_text`` applied last).
The study is ``lmap_drake.studies.hinge``; what the figures mean:
docs/explanation/planner-parameters.md (a turn about a wrong hinge).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from lmap_drake.errors import InputError, OneLineArgumentParser
from lmap_drake.studies.hinge import RunHinges, Summary


def main(argv=None) -> int:
    ap = OneLineArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=Path, nargs="+", required=True, help="simulated run folders")
    ap.add_argument("--scenario_text", default="{}", help="YAML overrides applied last")
    ap.add_argument("--out", type=Path, required=True, help="output JSON")
    args = ap.parse_args(argv)
    for r in args.runs:
        if not (r / "ground_truth.json").exists():
            ap.error(f"{r}: no ground_truth.json (a simulated run folder is needed)")
    tmp = args.out.with_suffix(args.out.suffix + ".part")
    runs = []
    try:
        for r in tqdm(args.runs, desc="runs", unit="run"):
            runs.append(RunHinges(r, args.scenario_text))
    except InputError as err:
        print(f"eval_hinge: {err}", file=sys.stderr)
        return 2
    rows = [row for run in runs for row in run["rows"]]
    out = {"runs": runs, "summary": Summary(rows)}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp.write_text(json.dumps(out, indent=1, default=lambda v: np.asarray(v).tolist()))
    tmp.replace(args.out)
    print(json.dumps(out["summary"], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
