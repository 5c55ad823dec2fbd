#!/usr/bin/env python3
"""Writes the UR5 and Robotiq 2F-85 URDFs in ``models/`` from their published
dimensions (``lmap_drake.robot_models``; the output is committed).

    python scripts/make_robot_models.py
"""
from __future__ import annotations

import argparse
import sys

from lmap_drake.errors import OneLineArgumentParser
from lmap_drake.robot_models import WriteRobotModels


def main(argv=None) -> None:
    OneLineArgumentParser(description=__doc__,
                            formatter_class=argparse.RawDescriptionHelpFormatter
                            ).parse_args(argv)
    ur5, robotiq = WriteRobotModels()
    print(f"wrote {ur5} and {robotiq}")


if __name__ == "__main__":
    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="make_robot_models.py", strip_debug=True))  # one-line errors; --debug
