"""``lmap-drake``: command-line entry point.

    lmap-drake run [--scenario_file F] [--scenario_name N] [--scenario_text YAML]
                   [--output DIR] [--hardware [--dry-run]]
"""
from __future__ import annotations

import argparse
import datetime as _dt
import sys
import time
from pathlib import Path

from lmap_drake.paths import DEFAULT_SCENARIO_FILE, DEFAULT_SCENARIO_NAME


def _add_scenario_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario_file", default=str(DEFAULT_SCENARIO_FILE),
                   help="scenario YAML (default: %(default)s)")
    p.add_argument("--scenario_name", default=DEFAULT_SCENARIO_NAME,
                   help="scenario inside the file (default: %(default)s)")
    p.add_argument("--scenario_text", default="{}",
                   help="YAML overrides applied last, e.g. \"{random_seed: 3}\"")
    p.add_argument("--output", default=None,
                   help="output folder (default: out/<timestamp>/)")


def _stage(msg: str) -> None:
    print(f"[lmap-drake] {msg}", flush=True)


def cmd_run(args) -> int:
    from lmap_drake.scenario import LoadScenario, ScenarioError
    from lmap_drake.episode import RunStationSnapshot

    try:
        scenario = LoadScenario(filename=args.scenario_file, scenario_name=args.scenario_name,
                                scenario_text=args.scenario_text)
    except ScenarioError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    if args.dry_run and not args.hardware:
        print("error: --dry-run needs --hardware", file=sys.stderr)
        return 2
    out = Path(args.output) if args.output else Path("out") / _dt.datetime.now().strftime(
        "%Y%m%d-%H%M%S")
    out.mkdir(parents=True, exist_ok=True)
    _stage(f"scenario '{args.scenario_name}' from {args.scenario_file}; output {out}")
    t0 = time.time()
    try:
        if args.hardware:
            from lmap_drake.station.hardware.run import RunHardwareSnapshot
            files = RunHardwareSnapshot(scenario, out, dry_run=args.dry_run, progress=_stage)
        elif scenario.plant_scene.kind == "procedural" and args.scripted:
            from lmap_drake.episode import RunScriptedPullEpisode
            files = RunScriptedPullEpisode(scenario, out, progress=_stage)
        elif scenario.plant_scene.kind == "procedural":
            from lmap_drake.episode import RunLmapEpisode
            files = RunLmapEpisode(scenario, out, progress=_stage)
        else:
            files = RunStationSnapshot(scenario, out, hardware=False, progress=_stage)
    except RuntimeError as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    _stage(f"done in {time.time() - t0:.1f} s; wrote " + ", ".join(sorted(files)))
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="lmap-drake", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run one simulated episode on a scenario")
    _add_scenario_args(run)
    run.add_argument("--hardware", action="store_true",
                     help="use the hardware station instead of the simulation")
    run.add_argument("--dry-run", action="store_true",
                     help="with --hardware: connect read-only, read state and one RGB-D "
                          "frame, plan and print the trajectory; command nothing")
    run.add_argument("--scripted", action="store_true",
                     help="execute the scenario's scripted pull (plant_scene.pull) instead "
                          "of planning with LMAP")
    run.set_defaults(func=cmd_run)
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
