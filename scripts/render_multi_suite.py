#!/usr/bin/env python3
"""Renders camera0 (colour | labels) of every multi-fruit scene to PNG and
measures its leaves: leaf-leaf interpenetration at rest (after settling) and
after a push (each leaf in turn flicked toward its nearest neighbour leaf),
the simulated seconds per wall second, and per-fruit visibility.

    python scripts/render_multi_suite.py                  # diagrams/multi_suite.yaml -> out/multi_suite/
    python scripts/render_multi_suite.py --no-push        # images only
    python scripts/render_multi_suite.py --scenario_text "{plant_scene: {multi: {leaf_leaf_contact: true}}}"

The study is ``lmap_drake.studies.multi_suite`` (``RenderScenePng`` and
``LabelColors`` can be used without the CLI).
"""
import argparse
import sys

from lmap_drake.errors import OneLineArgumentParser
from lmap_drake.paths import DIAGRAMS_DIR
from lmap_drake.studies.multi_suite import MeasureSuite


def main(argv=None) -> None:
    p = OneLineArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--suite", default=str(DIAGRAMS_DIR / "multi_suite.yaml"))
    p.add_argument("--out", default="out/multi_suite")
    p.add_argument("--scenario_text", default="{}")
    p.add_argument("--no-push", action="store_true")
    p.add_argument("--push_speed", type=float, default=1.5, help="m/s")
    p.add_argument("--only", default="", help="comma-separated scene names")
    a = p.parse_args(argv)
    MeasureSuite(a.suite, a.out, a.scenario_text, not a.no_push, a.push_speed, a.only)


if __name__ == "__main__":
    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="render_multi_suite.py", strip_debug=True))
