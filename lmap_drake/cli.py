"""``lmap-drake``: command-line entry point.

    lmap-drake run [--scenario_file F] [--scenario_name N] [--scenario_text YAML]
                   [--output DIR] [--overwrite] [--hardware] [--plan-only | --dry-run]
                   [--confirm | --no-confirm] [--speed_scale S] [--scripted] [--debug]
    lmap-drake replay RUN_DIR [--scenario_text YAML] [--output DIR] [--overwrite]
    lmap-drake replay BAG --calibration FILE [--time S | --index K] [--topics ROLE=T,..]
                      [--scenario_file F] [--scenario_name N] [--scenario_text YAML] [--output DIR]
    lmap-drake twin [--scenario_file F] [--scenario_name N] [--host H] [--rate R]
                    [--output DIR] [--overwrite] [--duration S]
                    [--fault K --fault_after_grasp_move D]
    lmap-drake eval [--scenario_file F | --scenarios N --seed S] [--methods M,..]
                    [--distances D,..] [--random_seeds K] [--scenario_names A,B]
                    [--workers W] [--output DIR] [--resume] [--debug]
                    [--engine pool|ray [--address HOST:PORT]] [--sweep FILE]
    lmap-drake train-segmenter --recordings DIR [--annotations COCO.json] --out W.pt
                    [--init W] [--sim_data DIR] [--sim_fraction F] [--steps N]

Exit codes: 0 done (or planned, with --plan-only), 1 error, 2 bad input
(scenario, weights, calibration, recording, bag, output folder, arguments),
3 episode aborted / no feasible action / not confirmed, 130 interrupted.
Errors are one line on stderr; --debug adds the traceback.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from lmap_drake.errors import (EXIT_ABORTED, EXIT_BAD_INPUT, InputError, OneLineArgumentParser,
                               RunMain)
from lmap_drake.limits import MAX_SCENARIOS
from lmap_drake.paths import DEFAULT_SCENARIO_FILE, DEFAULT_SCENARIO_NAME
from lmap_drake.studies.segmenter_finetune_args import AddArguments as AddTrainSegmenterArgs


class UsageError(InputError):
    """A bad command-line value."""


def _add_scenario_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario_file", default=str(DEFAULT_SCENARIO_FILE),
                   help="scenario YAML (default: %(default)s)")
    p.add_argument("--scenario_name", default=DEFAULT_SCENARIO_NAME,
                   help="scenario inside the file (default: %(default)s)")
    p.add_argument("--scenario_text", default="{}",
                   help="YAML overrides applied last, e.g. \"{random_seed: 3}\"")
    p.add_argument("--output", default=None,
                   help="output folder (default: out/<timestamp>-<random>/); written "
                        "complete or not at all")


def _stage(msg: str) -> None:
    print(f"[lmap-drake] {msg}", flush=True)


def cmd_run(args) -> int:
    from lmap_drake.outputs import DefaultOutputFolder, OutputFolder
    from lmap_drake.scenario import LoadScenario

    scenario = LoadScenario(filename=args.scenario_file, scenario_name=args.scenario_name,
                            scenario_text=args.scenario_text)
    if args.dry_run and not args.hardware:
        raise UsageError("--dry-run needs --hardware (in simulation use --plan-only)")
    plan_only = args.plan_only or args.dry_run
    if args.speed_scale is not None:
        if not 0.0 < args.speed_scale <= 1.0:
            raise UsageError(f"--speed_scale must be in (0, 1], got {args.speed_scale}")
        scenario.planner.speed_scale = args.speed_scale
    if args.scripted and (args.hardware or plan_only):
        raise UsageError("--scripted runs the simulated scripted pull; it does not combine "
                         "with --hardware, --plan-only or --dry-run")
    if args.hardware:       # the device-free part of the pre-motion gate, before any output
        from lmap_drake.station.hardware.station import CheckHardwareScenario
        CheckHardwareScenario(scenario)
    # On the real cell the operator confirms the action unless told otherwise.
    confirm = args.hardware if args.confirm is None else args.confirm
    final = Path(args.output) if args.output else DefaultOutputFolder()
    folder = OutputFolder(final, overwrite=args.overwrite, command="run",
                          inputs=[args.scenario_file])
    _stage(f"scenario '{args.scenario_name}' from {args.scenario_file}; output {final}"
           + ("; hardware" if args.hardware else "") + ("; plan only" if plan_only else ""))
    t0 = time.time()
    status = "done"
    with folder as out:
        if args.hardware or (scenario.plant_scene.kind in ("procedural", "multi", "greenhouse", "mesh_plant")
                             and not args.scripted):
            from lmap_drake.episode import RunLmapEpisode
            files, status = RunLmapEpisode(scenario, out, progress=_stage,
                                           hardware=args.hardware, plan_only=plan_only,
                                           confirm=confirm and not plan_only)
        elif args.scripted:
            if scenario.plant_scene.kind != "procedural":
                raise UsageError("--scripted needs plant_scene.kind: procedural")
            from lmap_drake.episode import RunScriptedPullEpisode
            files = RunScriptedPullEpisode(scenario, out, progress=_stage)
        else:
            from lmap_drake.episode import RunStationSnapshot
            files = RunStationSnapshot(scenario, out, progress=_stage)
    if folder.final != final:
        _stage(f"warning: {final} was filled by another run meanwhile; this run's outputs "
               f"are in {folder.final}")
    _stage(f"done in {time.time() - t0:.1f} s; wrote {folder.final}/: "
           + ", ".join(sorted(f for f in files if not f.startswith("recording/")))
           + (", recording/" if any(f.startswith("recording/") for f in files) else ""))
    if status not in ("done", "planned"):
        _stage(f"episode {status} (exit code {EXIT_ABORTED})")
        return EXIT_ABORTED
    return 0


def cmd_replay(args) -> int:
    from lmap_drake.outputs import DefaultOutputFolder, OutputFolder
    from lmap_drake.perception.bags import IsBag
    from lmap_drake.perception.recording import LoadRecording
    from lmap_drake.scenario import LoadScenario

    from lmap_drake.episode.replay import ReadRunPlan

    run_dir = Path(args.run_dir)
    if IsBag(run_dir):
        return _ReplayBag(args)
    if args.time is not None or args.index is not None or args.topics or args.calibration:
        raise UsageError("--time, --index, --topics and --calibration are for replaying a bag; "
                         f"{run_dir} is not a .bag file or a ROS 2 bag folder")
    if run_dir.exists() and not run_dir.is_dir():
        raise UsageError(f"{run_dir} is a file, not a run folder")
    if not run_dir.is_dir():
        raise UsageError(f"run folder {run_dir} not found")
    LoadRecording(run_dir)                       # bad recording: fail before building
    ReadRunPlan(run_dir)                         # a broken plan.json too
    LoadScenario(scenario_text=args.scenario_text)
    final = Path(args.output) if args.output else DefaultOutputFolder(prefix="replay-")
    folder = OutputFolder(final, overwrite=args.overwrite, command="replay", inputs=[run_dir])
    t0 = time.time()
    with folder as out:
        from lmap_drake.episode import ReplayRun
        files, record = ReplayRun(run_dir, out, args.scenario_text, progress=_stage)
    _stage(f"done in {time.time() - t0:.1f} s; wrote {folder.final}/: "
           + ", ".join(sorted(files)))
    return 0 if record["status"] in ("ok", "no_action_needed") else EXIT_ABORTED


def _ReplayBag(args) -> int:
    """``lmap-drake replay BAG``: the bag's view converted into the output
    folder's ``recording/``, then replayed (``episode.bag_replay``)."""
    from lmap_drake.outputs import DefaultOutputFolder, OutputFolder
    from lmap_drake.perception.bags import ParseTopics
    from lmap_drake.scenario import LoadScenario

    if not args.calibration:
        raise UsageError(f"replaying the bag {args.run_dir} needs --calibration FILE (the "
                         f"camera pose X_WC; format: diagrams/calibration_example.yaml)")
    if args.index is not None and args.index < 0:
        raise UsageError(f"--index must be >= 0, got {args.index}")
    if args.time is not None and not args.time >= 0:
        raise UsageError(f"--time must be >= 0 s from the bag's start, got {args.time}")
    topics = ParseTopics(args.topics)
    # the scenario is written as the converted run's; the replay applies the
    # overrides to it (loaded here too: a bad override fails now)
    scenario = LoadScenario(filename=args.scenario_file, scenario_name=args.scenario_name)
    overridden = LoadScenario(filename=args.scenario_file, scenario_name=args.scenario_name,
                              scenario_text=args.scenario_text)
    from lmap_drake.episode.bag_replay import LoadBagView, ReplayBag
    capture, X_WC = LoadBagView(args.run_dir, args.calibration, overridden, time=args.time,
                                index=args.index, topics=topics)   # a bad bag fails now
    final = Path(args.output) if args.output else DefaultOutputFolder(prefix="replay-")
    folder = OutputFolder(final, overwrite=args.overwrite)
    t0 = time.time()
    with folder as out:
        files, record = ReplayBag(capture, X_WC, scenario, out, args.scenario_text,
                                  args.calibration, progress=_stage)
    _stage(f"done in {time.time() - t0:.1f} s; wrote {folder.final}/: "
           + ", ".join(sorted(f for f in files if not f.startswith("recording/")))
           + ", recording/")
    return 0 if record["status"] in ("ok", "no_action_needed") else EXIT_ABORTED


def cmd_twin(args) -> int:
    """The digital twin until Ctrl-C, SIGTERM, a ``quit`` line on stdin or
    ``--duration`` wall seconds; then it writes its outcome. Its output
    folder is claimed (lock, marker, --overwrite rules) before anything is
    built."""
    from lmap_drake.outputs import DefaultOutputFolder, InPlaceFolder
    from lmap_drake.scenario import LoadScenario

    scenario = LoadScenario(filename=args.scenario_file, scenario_name=args.scenario_name,
                            scenario_text=args.scenario_text)
    if scenario.plant_scene.kind != "procedural":
        raise UsageError("the twin needs plant_scene.kind: procedural (the FEM plant world)")
    if not 0.0 < args.rate <= 1.0:
        raise UsageError(f"--rate must be in (0, 1] simulated s per wall s, got {args.rate}")
    warning = _CheckTwinArgs(args)
    folder = InPlaceFolder(args.output or DefaultOutputFolder(prefix="twin-"), "twin", {},
                           overwrite=args.overwrite, inputs=[args.scenario_file])
    with folder:
        return _ServeTwin(args, scenario, warning, folder.Start())


def _ServeTwin(args, scenario, warning, out: Path) -> int:
    import signal
    import threading

    from lmap_drake.twin.twin import Twin, TwinOptions, TwinRunOverrides, WriteTwinCalibration
    calibration = (out / "calibration.yaml").resolve()
    options = TwinOptions(host=args.host, camera_port=args.camera_port,
                          gripper_port=args.gripper_port, rate=args.rate,
                          fault=args.fault, fault_after_grasp_move=args.fault_after_grasp_move,
                          allow_remote=args.allow_remote, log_dir=str(out))
    if warning:
        _stage(warning)
    _stage("building the plant world")
    twin = Twin(scenario, options, progress=_stage)
    WriteTwinCalibration(scenario, calibration)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    if args.duration > 0:
        timer = threading.Timer(args.duration, stop.set)
        timer.daemon = True
        timer.start()

    def read_stdin():
        for line in sys.stdin:
            if line.strip() == "quit":
                stop.set()
                return
    threading.Thread(target=read_stdin, daemon=True).start()
    try:
        twin.Start()
        text = TwinRunOverrides(options, str(calibration))
        _stage(f"twin ready at {args.host} (UR emulator, Robotiq {args.gripper_port}, camera "
               f"{args.camera_port}), {args.rate:g} simulated s per wall s; run the episode "
               f"with:")
        print(f"  lmap-drake run --hardware --no-confirm --scenario_file {args.scenario_file} "
              f"--scenario_name {args.scenario_name} --scenario_text \"{text}\"", flush=True)
        twin.Run(stop)
    finally:
        twin.Close()
    outcome = twin.Finish(out)
    _stage(f"twin stopped after {twin.world.time:.1f} simulated s (largest lag "
           f"{twin.lag_max:.2f} s); outcome: " + json.dumps(
               {k: v for k, v in outcome.items() if k != "release_outcome"}))
    _stage(f"wrote {out}/: outcome.json, twin_log.json, calibration.yaml, ur_emulator.log")
    return 0


def _CheckTwinArgs(args) -> str:
    """The twin's options, before anything is built or written: ports
    1..65535, a loopback --host unless --allow_remote (then the returned
    warning), finite --duration and --fault_after_grasp_move >= 0."""
    import math

    from lmap_drake.twin.listen import CheckPort, ListenError, ListenHostWarning
    try:
        CheckPort(args.camera_port, "--camera_port")
        CheckPort(args.gripper_port, "--gripper_port")
        warning = ListenHostWarning(args.host, args.allow_remote)
    except ListenError as err:
        raise UsageError(str(err)) from None
    for option in ("duration", "fault_after_grasp_move"):
        value = getattr(args, option)
        if not (math.isfinite(value) and value >= 0):
            raise UsageError(f"--{option} must be a finite number >= 0, got {value}")
    return warning


def _CheckEvalArgs(args) -> tuple[list[str], list[float]]:
    from lmap_drake.evaluation import tables as T
    if not 0 <= args.scenarios <= MAX_SCENARIOS:
        raise UsageError(f"--scenarios must be in [1, {MAX_SCENARIOS}] (0: use "
                         f"--scenario_file), got {args.scenarios}")
    if args.workers < 1:
        raise UsageError(f"--workers must be >= 1, got {args.workers}")
    if args.address and args.engine != "ray":
        raise UsageError("--address needs --engine ray")
    if args.engine == "ray":
        from lmap_drake.evaluation.engines import ImportRay
        ImportRay(local=not args.address)        # a missing Ray fails now, in one line
        if args.address:                          # no cluster there: before any folder
            from lmap_drake.evaluation.engines import CheckAddress
            CheckAddress(args.address)
    if args.seed < 0:
        raise UsageError(f"--seed must be >= 0, got {args.seed}")
    if not 0.0 < args.visibility_success <= 1.0:
        raise UsageError(f"--visibility_success must be in (0, 1], got {args.visibility_success}")
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    if not methods:
        raise UsageError(f"--methods is empty; choose from {', '.join(T.METHODS)}")
    unknown = [m for m in methods if m not in T.METHODS]
    if unknown:
        raise UsageError(f"--methods: unknown {', '.join(unknown)}; choose from "
                         f"{', '.join(T.METHODS)}")
    try:
        distances = [float(d) for d in args.distances.split(",") if d.strip()]
    except ValueError:
        raise UsageError(f"--distances must be comma-separated metres, got "
                         f"{args.distances!r}") from None
    if any(m in T.BASELINES for m in methods):
        if not distances:
            raise UsageError("--distances is empty but a baseline method needs at least one")
        bad = [d for d in distances if not (d > 0 and d < float("inf"))]
        if bad:
            raise UsageError(f"--distances must be positive metres, got {bad}")
    if "random" in methods and args.random_seeds < 1:
        raise UsageError(f"--random_seeds must be >= 1 for the random method, got "
                         f"{args.random_seeds}")
    return methods, distances


def _SweepSpecs(specs: list[dict], sweep, points: list[dict], labels: list[str],
                suite_file, sweep_file) -> list[list[dict]]:
    """The suite's specs once per grid point, each carrying the point's
    override, resolved (a scenario that does not load with a point's values
    fails now, naming the point and the sweep file)."""
    from lmap_drake.evaluation import sweep as S
    from lmap_drake.evaluation.run_eval import EVAL_KINDS, ResolveSpecs
    from lmap_drake.scenario import ScenarioError
    out = []
    for p, label in zip(points, labels):
        text = S.OverrideText(p)
        group = [dict(s, sweep_text=text, sweep_point=label, sweep_values=p) for s in specs]
        try:
            ResolveSpecs(group, suite_file, kinds=EVAL_KINDS)
        except ScenarioError as err:
            raise S.SweepError(f"{sweep_file}: grid point {text}: "
                               f"{str(err).replace('--scenario_text', 'the sweep')}") from None
        out.append(group)
    return out


def _CheckOverride(text: str) -> None:
    """Fails fast on an eval-wide ``--scenario_text`` that no plant kind can
    take (unknown keys, wrong types, bad values). An override that is only
    valid with a suite's own entries (e.g. ``plant_scene.fruit.mesh_file``,
    which needs ``kind: procedural``) passes here; every episode's full
    scenario is checked before anything runs (``ResolveSpecs``)."""
    from lmap_drake.scenario import LoadScenario
    first = None
    for kind in ("procedural", None, "multi", "greenhouse"):
        base = [] if kind is None else ["{plant_scene: {kind: %s}}" % kind]
        try:
            LoadScenario(scenario_text=base + [text])
            return
        except Exception as err:  # noqa: BLE001 - the first error is the one to show
            first = first or err
    raise first


def cmd_eval(args) -> int:
    from lmap_drake.evaluation.run_eval import EvalOptions, HasRecords
    from lmap_drake.outputs import DefaultOutputFolder, InPlaceFolder

    methods, distances = _CheckEvalArgs(args)
    _CheckOverride(args.scenario_text)      # fail now on a bad override
    sweep = points = labels = None
    if args.sweep:
        from lmap_drake.evaluation import sweep as S
        sweep = S.LoadSweep(args.sweep)
        points = S.CheckPoints(sweep, args.sweep, args.scenario_text)
        labels = [S.PointLabel(i, p) for i, p in enumerate(points)]
    out = Path(args.output) if args.output else DefaultOutputFolder(prefix="eval-")
    options = EvalOptions(args.scenarios, args.seed, args.scenario_file, args.scenario_names,
                          methods, distances, args.random_seeds, args.scenario_text,
                          Path(args.sweep).read_text() if args.sweep else None)
    # Claimed (locked, checked) before anything is written; a folder this
    # eval made is removed again if it fails before its first record.
    with InPlaceFolder(out, "eval", options, resume=args.resume, kept=HasRecords,
                       legacy=("episodes.jsonl", "sweep.yaml")) as folder:
        summary = _RunEval(args, folder, methods, distances, sweep, points, labels)
    for eid, msg in summary["errors"]:
        print(f"error in {eid}: {msg}", file=sys.stderr)
    return 1 if summary["errors"] else 0


def _RunEval(args, folder, methods, distances, sweep, points, labels) -> dict:
    from lmap_drake.evaluation import tables as T
    from lmap_drake.evaluation.run_eval import (EVAL_KINDS, EvalConflict, ResolveSpecs,
                                                RunEvaluation, RunSweep)
    from lmap_drake.scenario import RawYaml, ReadScenarioFile
    out = folder.path
    if args.scenarios:
        from lmap_drake.evaluation.progress import Progress
        from lmap_drake.plants.suite import RandomSuite, SuiteYaml
        from lmap_drake.scenario import IsEmptyOverride
        # The draws are checked with --scenario_text applied (e.g. a pepper
        # mesh of the user's that a drawn leaf cannot hide as asked).
        over = "" if IsEmptyOverride(args.scenario_text) else args.scenario_text
        _stage(f"eval: drawing {args.scenarios} random scene(s) from seed {args.seed}, each "
               f"built once by the plant generator" +
               (" with --scenario_text applied" if over else ""))
        with Progress(args.scenarios, desc="scenes", unit="scene") as bar:
            suite = RandomSuite(args.scenarios, args.seed, scenario_text=args.scenario_text,
                                on_scene=bar.Step)
        text = SuiteYaml(suite, f"# RandomSuite({args.scenarios}, {args.seed})" +
                         (f", buildable with the overrides {' '.join(over.split())}"
                          if over else ""))
        suite_file = out / "suite.yaml"        # never overwritten
        if suite_file.exists() and suite_file.read_text() != text:
            raise EvalConflict(f"{suite_file} differs from RandomSuite({args.scenarios}, "
                               f"{args.seed}) drawn now: --resume would mix suites; use "
                               "another --output")
        folder.Start()                          # after the draws: a suite that cannot be
        if not suite_file.exists():             # drawn leaves no folder behind
            suite_file.write_text(text)
    else:
        suite_file = Path(args.scenario_file)
    raw = RawYaml(ReadScenarioFile(suite_file), str(suite_file))
    if not isinstance(raw, dict) or not raw:
        raise UsageError(f"{suite_file} holds no named scenarios")
    names = list(raw)
    if args.scenario_names:
        wanted = [n for n in args.scenario_names.split(",") if n]
        missing = [n for n in wanted if n not in names]
        if missing:
            raise UsageError(f"not in {suite_file}: {', '.join(missing)}")
        names = wanted
    specs = T.EpisodeSpecs(names, methods, distances, args.random_seeds, args.seed,
                           args.scenario_text)
    if not specs:
        raise UsageError("no episodes to run (check --methods, --distances, --random_seeds)")
    run_args = dict(workers=args.workers, engine=args.engine, address=args.address or None,
                    resume=args.resume, progress=lambda m: _stage(f"eval: {m}"),
                    threshold=args.visibility_success)
    if sweep is not None:
        point_specs = _SweepSpecs(specs, sweep, points, labels, suite_file, args.sweep)
        folder.Start()
        return RunSweep(point_specs, sweep, points, labels, args.sweep, suite_file, out,
                        **run_args)
    ResolveSpecs(specs, suite_file, kinds=EVAL_KINDS)   # every episode's scenario: bad
    folder.Start()                                       # input fails now
    return RunEvaluation(specs, suite_file, out, **run_args)


def cmd_train_segmenter(args) -> int:
    from lmap_drake.studies.segmenter_finetune import FineTuneSegmenter
    FineTuneSegmenter(args)
    return 0


def main(argv=None) -> int:
    """The entry point: one top-level handler turns every error into a
    one-line message and an exit code (``lmap_drake.errors``)."""
    return RunMain(_main, argv, prog="lmap-drake")


def _main(argv=None) -> int:
    parser = OneLineArgumentParser(prog="lmap-drake", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--debug", action="store_true", help="show tracebacks")
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run one LMAP episode on the simulated station "
                         "(default) or the real cell (--hardware)")
    _add_scenario_args(run)
    run.add_argument("--overwrite", action="store_true",
                     help="replace an existing lmap-drake output folder (one holding the "
                          ".lmap_drake marker; never the input being read)")
    run.add_argument("--debug", action="store_true", help="show tracebacks")
    run.add_argument("--hardware", action="store_true",
                     help="use the hardware station instead of the simulation")
    run.add_argument("--plan-only", action="store_true",
                     help="capture, plan, write the candidates, the chosen action and a "
                          "picture of the predicted deformation over the camera image; "
                          "move nothing (on hardware the robot is connected read-only)")
    run.add_argument("--dry-run", action="store_true",
                     help="with --hardware: the same as --plan-only")
    run.add_argument("--confirm", dest="confirm", action="store_true", default=None,
                     help="show the chosen action with its predicted energy and visibility "
                          "and move only after the operator types yes (default on hardware)")
    run.add_argument("--no-confirm", dest="confirm", action="store_false",
                     help="execute the chosen action without asking")
    run.add_argument("--speed_scale", type=float, default=None,
                     help="scale every arm motion, in (0, 1] (planner.speed_scale; on "
                          "hardware also bounded by hardware.ur.joint_speed_limit)")
    run.add_argument("--scripted", action="store_true",
                     help="execute the scenario's scripted pull (plant_scene.pull) instead "
                          "of planning with LMAP")
    run.set_defaults(func=cmd_run)
    rp = sub.add_parser("replay", help="re-run perception, shape completion and planning "
                        "offline on a run's recording (its recording/ folder)")
    rp.add_argument("run_dir", help="output folder of a simulated or hardware run, or a "
                    "RealSense .bag / ROS 1 .bag file / ROS 2 bag folder")
    rp.add_argument("--scenario_text", default="{}",
                    help="YAML overrides applied to the run's scenario.yaml (a bag: to "
                         "--scenario_file's scenario), e.g. "
                         "\"{planner: {energy_weight: 0.5}}\"")
    rp.add_argument("--calibration", default="",
                    help="a bag: the camera calibration file giving X_WC (format: "
                         "diagrams/calibration_example.yaml)")
    rp.add_argument("--time", type=float, default=None,
                    help="a bag: the colour frame nearest this many s from the bag's start")
    rp.add_argument("--index", type=int, default=None,
                    help="a bag: colour frame number (0 = first, the default)")
    rp.add_argument("--topics", default="",
                    help="a bag: topics by role, e.g. color=/camera/color/image_raw,"
                         "depth=/camera/aligned_depth_to_color/image_raw,info=/camera/color/"
                         "camera_info (also depth_info=, joints=); found when not given")
    rp.add_argument("--scenario_file", default=str(DEFAULT_SCENARIO_FILE),
                    help="a bag: the scenario YAML to plan with (default: %(default)s)")
    rp.add_argument("--scenario_name", default=DEFAULT_SCENARIO_NAME,
                    help="a bag: the scenario inside the file (default: %(default)s)")
    rp.add_argument("--output", default=None,
                    help="output folder (default: out/replay-<timestamp>-<random>/)")
    rp.add_argument("--overwrite", action="store_true",
                    help="replace an existing lmap-drake output folder (one holding the "
                          ".lmap_drake marker; never the input being read)")
    rp.add_argument("--debug", action="store_true", help="show tracebacks")
    rp.set_defaults(func=cmd_replay)
    tw = sub.add_parser("twin", help="the digital twin: the simulated plant world behind a UR "
                        "controller emulator, a Robotiq socket and a camera socket, for "
                        "lmap-drake run --hardware with the real ur_rtde client")
    _add_scenario_args(tw)
    tw.add_argument("--host", default="127.0.0.1",
                    help="loopback address to listen on (default: %(default)s; another "
                         "address needs --allow_remote)")
    tw.add_argument("--allow_remote", action="store_true",
                    help="allow a --host that is not loopback: the robot-control ports have "
                         "no authentication (a warning is printed)")
    tw.add_argument("--camera_port", type=int, default=50410, help="camera socket port")
    tw.add_argument("--gripper_port", type=int, default=63352, help="Robotiq URCap port")
    tw.add_argument("--rate", type=float, default=0.5,
                    help="simulated seconds per wall second (default: %(default)s)")
    tw.add_argument("--duration", type=float, default=0.0,
                    help="stop after this many wall seconds (0: until Ctrl-C or 'quit')")
    tw.add_argument("--fault", default="protective_stop",
                    choices=("protective_stop", "emergency_stop", "drop"),
                    help="the fault --fault_after_grasp_move injects (default: %(default)s)")
    tw.add_argument("--fault_after_grasp_move", type=float, default=0.0,
                    help="inject --fault once the held leaf moved this far (m); 0: never")
    tw.add_argument("--overwrite", action="store_true",
                    help="replace an existing lmap-drake output folder (one holding the "
                         ".lmap_drake marker; never the input being read)")
    tw.add_argument("--debug", action="store_true", help="show tracebacks")
    tw.set_defaults(func=cmd_twin)
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
    ev.add_argument("--workers", type=int, default=2,
                    help="worker processes (pool), or CPUs of the local Ray instance")
    ev.add_argument("--engine", choices=("pool", "ray"), default="pool",
                    help="pool: worker processes on this machine (default); ray: Ray tasks "
                         "on a local instance or, with --address, a cluster (needs "
                         "pip install -e '.[ray]')")
    ev.add_argument("--address", default="",
                    help="with --engine ray: the cluster's HOST:PORT (`ray start --head` "
                         "prints it) or auto")
    ev.add_argument("--sweep", default="",
                    help="YAML grid of scenario overrides (dotted key: [values]; several keys: "
                         "cartesian product) crossed with the suite: one folder and table per "
                         "grid point, sweep_summary.json/.png (e.g. "
                         "diagrams/sweep_energy_weight.yaml)")
    ev.add_argument("--visibility_success", type=float, default=0.95,
                    help="Table V: final visibility counted as sufficient")
    ev.add_argument("--output", default=None,
                    help="output folder (default: out/eval-<timestamp>-<random>/)")
    ev.add_argument("--debug", action="store_true", help="show tracebacks")
    ev.add_argument("--resume", action="store_true",
                    help="continue OUTPUT/episodes.jsonl: skip episodes already recorded "
                         "(errors are re-run)")
    ev.set_defaults(func=cmd_eval)
    ts = sub.add_parser("train-segmenter", help="fine-tune the segmentation network on "
                        "annotated recordings (COCO or LabelMe polygons)")
    AddTrainSegmenterArgs(ts)
    ts.set_defaults(func=cmd_train_segmenter)
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
