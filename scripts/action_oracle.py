#!/usr/bin/env python
"""How much of the fruit can one safe pull reveal in the FEM plant world?
Executes the LMAP planner's best-looking candidates, not only its choice.

    python scripts/action_oracle.py --out out/oracle.json
    python scripts/action_oracle.py --out o.json --top 6 \
        --scenario_names small_leaf_thin_branch_round_red_heavy

The study is ``lmap_drake.studies.action_oracle`` (what is executed, how it
is scored, the JSON it writes).
"""
from __future__ import annotations

import argparse
import sys

from lmap_drake.errors import OneLineArgumentParser
from lmap_drake.studies.action_oracle import SUITE, RunOracle


def main(argv=None) -> int:
    p = OneLineArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True, help="JSON file to write")
    p.add_argument("--scenario_file", default=str(SUITE))
    p.add_argument("--scenario_names", default="", help="comma-separated (default: all)")
    p.add_argument("--top", type=int, default=6, help="candidates executed per scene")
    p.add_argument("--energy_weight", type=float, default=1.0)
    p.add_argument("--workers", type=int, default=2)
    a = p.parse_args(argv)
    return RunOracle(**vars(a))


if __name__ == "__main__":
    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="action_oracle.py", strip_debug=True))  # one-line errors; --debug
