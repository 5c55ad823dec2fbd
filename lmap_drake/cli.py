"""``lmap-drake``: command-line entry point.

    lmap-drake run [--scenario_file F] [--scenario_name N] [--scenario_text YAML]
                   [--output DIR] [--hardware [--dry-run]]
    lmap-drake eval [--scenario_file F | --scenarios N --seed S] [--methods M,..]
                    [--distances D,..] [--random_seeds K] [--scenario_names A,B]
                    [--workers W] [--output DIR] [--resume]
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


def cmd_eval(args) -> int:
    from lmap_drake.evaluation import tables as T
    from lmap_drake.evaluation.run_eval import RunEvaluation
    from lmap_drake.scenario import _RawYaml

    out = Path(args.output) if args.output else Path("out") / (
        "eval-" + _dt.datetime.now().strftime("%Y%m%d-%H%M%S"))
    out.mkdir(parents=True, exist_ok=True)
    if args.scenarios:
        from lmap_drake.plants.suite import RandomSuite, SuiteYaml
        suite_file = out / "suite.yaml"
        suite_file.write_text(SuiteYaml(RandomSuite(args.scenarios, args.seed),
                                        f"# RandomSuite({args.scenarios}, {args.seed})"))
    else:
        suite_file = Path(args.scenario_file)
    if not suite_file.exists():
        print(f"error: scenario file not found: {suite_file}", file=sys.stderr)
        return 2
    names = list(_RawYaml(suite_file.read_text()) or {})
    if args.scenario_names:
        wanted = [n for n in args.scenario_names.split(",") if n]
        missing = [n for n in wanted if n not in names]
        if missing:
            print(f"error: not in {suite_file}: {', '.join(missing)}", file=sys.stderr)
            return 2
        names = wanted
    try:
        methods = [m for m in args.methods.split(",") if m]
        distances = [float(d) for d in args.distances.split(",") if d]
        specs = T.EpisodeSpecs(names, methods, distances, args.random_seeds, args.seed,
                               args.scenario_text)
        from lmap_drake.scenario import LoadScenario
        LoadScenario(scenario_text=args.scenario_text)      # fail now on a bad override
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    try:
        summary = RunEvaluation(specs, suite_file, out, workers=args.workers,
                                resume=args.resume, progress=lambda m: _stage(f"eval: {m}"),
                                threshold=args.visibility_success)
    except FileExistsError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    for eid, msg in summary["errors"]:
        print(f"error in {eid}: {msg}", file=sys.stderr)
    return 1 if summary["errors"] else 0


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
    ev = sub.add_parser("eval", help="run a scenario suite with LMAP and the baselines; "
                        "write the Table II-V analogues")
    ev.add_argument("--scenario_file", default=str(DEFAULT_SCENARIO_FILE.parent / "suite.yaml"),
                    help="suite of named scenarios (default: %(default)s)")
    ev.add_argument("--scenarios", type=int, default=0,
                    help="instead: N random scenarios from RandomSuite(N, --seed)")
    ev.add_argument("--seed", type=int, default=0,
                    help="RandomSuite seed, and the first planner random_seed")
    ev.add_argument("--scenario_names", default="",
                    help="comma-separated subset of the suite's scenarios")
    ev.add_argument("--methods", default="random,upward,min_overlap,lmap,lmap_lambda0",
                    help="comma-separated methods (default: %(default)s)")
    ev.add_argument("--distances", default="0.02,0.04,0.06,0.08",
                    help="baseline move distances, metres (default: %(default)s)")
    ev.add_argument("--random_seeds", type=int, default=5,
                    help="Random-baseline trials per scenario and distance")
    ev.add_argument("--scenario_text", default="{}",
                    help="YAML overrides for every episode, applied before each method's own "
                         "(e.g. '{planner: {max_energy_per_node: 0.0}}')")
    ev.add_argument("--workers", type=int, default=2, help="worker processes")
    ev.add_argument("--visibility_success", type=float, default=0.95,
                    help="Table V: final visibility counted as sufficient")
    ev.add_argument("--output", default=None, help="output folder (default: out/eval-<time>/)")
    ev.add_argument("--resume", action="store_true",
                    help="continue OUTPUT/episodes.jsonl: skip episodes already recorded "
                         "(errors are re-run)")
    ev.set_defaults(func=cmd_eval)
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
