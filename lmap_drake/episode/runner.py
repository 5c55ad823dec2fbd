"""The episode runner: one loop for the simulated and the hardware station.

``RunEpisode`` steps the whole Diagram (``diagram.MakeEpisodeDiagram``)
around a station until the ``ArmController`` is finished: observe, plan,
[confirm], pre-grasp, approach, grasp, pull, hold, observe again, fuse,
re-estimate, release, retreat. What differs between the two stations lives
in a *world adapter*: ``episode.sim_world.SimWorld`` (the FEM plant world,
scored against the ground truth) or ``episode.hardware_world.HardwareWorld``
(the real cell, paced by the wall clock). ``RunLmapEpisode`` is
``lmap-drake run``: it builds the world, runs the episode and writes it
(``episode.records.SaveEpisode``); ``RunSimEpisode`` is one simulated
episode for ``lmap-drake eval``. World frame W, metres, seconds, radians.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

from pydrake.geometry import Meshcat

from lmap_drake.diagram import EpisodeResources, WriteDiagramSvg
from lmap_drake.episode.hardware_world import HardwareWorld
from lmap_drake.episode.records import (DescribePlan, EpisodeResult, HypothesesRecord,
                                        OutcomeLine, SaveEpisode)
from lmap_drake.episode.sim_world import FrameMeshcat, SimWorld
from lmap_drake.plants.generator import SaveGroundTruth
from lmap_drake.plants.multi import MULTI_KINDS, NumPlantFruits, SaveMultiGroundTruth
from lmap_drake.scenario import DumpScenario, Scenario
from lmap_drake.station.camera_noise import CameraProfile
from lmap_drake.station.hardware.run import PrepareHardware
from lmap_drake.station.hardware.safety import HardwareAbort, SafetyChecker
from lmap_drake.systems.arm_controller import ControllerOptions
from lmap_drake.systems.view_recorder import ViewImages


def ControllerOptionsFor(scenario: Scenario, hardware: bool, plan_only: bool = False,
                         confirm: bool = False, initial_q=None, initial_gripper=None):
    """The ArmController's options on the simulated or the hardware station."""
    opts = ControllerOptions(initial_q=initial_q, initial_gripper=initial_gripper,
                             grasp_ack_required=not hardware, plan_only=plan_only,
                             confirm=confirm, release=scenario.planner.release_and_retreat)
    if hardware:
        checker = SafetyChecker(scenario.hardware.ur)
        opts.max_joint_speed = scenario.hardware.ur.joint_speed_limit
        opts.trajectory_check = checker.CheckTrajectory
    return opts


def RunEpisode(scenario: Scenario, world, progress: Callable[[str], None] | None = None,
               max_time: float = 60.0, confirm: Callable | None = None) -> EpisodeResult:
    """Steps ``world`` (``SimWorld`` or ``HardwareWorld``) until its
    controller is finished (or ``max_time`` station seconds). ``confirm(plan)
    -> (accepted, note)`` answers the controller's ``confirm_wait``. A
    ``HardwareAbort`` or any exception inside the Diagram ends the episode
    with status ``aborted`` and a message (the world stops its arm)."""
    progress = progress or (lambda m: None)
    wall0 = time.perf_counter()

    def controller():
        c = world.diagram.GetSubsystemByName("arm_controller")
        return c, c.GetMyContextFromRoot(world.context)
    step_wall = 0.0
    mode_wall: dict[str, float] = {}     # wall seconds of the steps begun in each mode
    mode = "idle"
    error = ""
    dt = 0.05
    try:
        world.Start()
        while world.time < max_time:
            t0 = time.perf_counter()
            world.Step(dt)
            took = time.perf_counter() - t0
            step_wall += took
            mode_wall[mode] = mode_wall.get(mode, 0.0) + took
            c, cctx = controller()
            st = c.Status(cctx)
            mode = st.mode
            if st.finished:
                break
            # While the pads close, the grasp is made at the first 10 ms tick
            # at which they reach the attach opening: a 50 ms tick let a
            # squeeze push the thin leaf out first in one run of a scene and
            # not in another.
            dt = 0.01 if st.mode == "close_gripper" else 0.05
            if st.mode == "confirm_wait" and st.confirmed is None:
                asked = st.pending_motion[0] if st.pending_motion is not None else st.plan
                accepted, note = confirm(asked) if confirm is not None else (
                    False, "no operator to confirm")
                c.Confirm(cctx, accepted, note)
                world.Pause()
                continue
            if st.mode == "plan_requested" or st.mode == "observe":
                world.Pause()
            message = world.AfterStep(c, cctx, st)
            if message:
                error = message
                progress(f"aborted: {message}")
                break
    except KeyboardInterrupt:
        raise
    except Exception as err:  # noqa: BLE001 - a HardwareAbort, or a failure in the Diagram
        kind = "hardware" if isinstance(err, HardwareAbort) else "stage_error: diagram"
        error = (f"{kind} at t = {world.time:.2f} s: "
                 + (str(err) if isinstance(err, HardwareAbort) else
                    f"{type(err).__name__}: {' '.join(str(err).split())}"))
        progress(f"aborted: {error}")
    c, cctx = controller()
    st = c.Status(cctx)
    views = tuple(world.diagram.GetSubsystemByName("view_recorder").GetOutputPort(
        "views").Eval(world.diagram.GetSubsystemByName("view_recorder").GetMyContextFromRoot(
            world.context)))

    def images(view):
        rgb, depth, label = ViewImages(view)
        return {"rgb_image": rgb, "depth_image": depth, "label_image": label}
    current = world.CurrentImages()
    before = images(views[0]) if views else current
    after = images(views[-1]) if len(views) >= 2 else current
    plan = st.plan
    chosen = plan.chosen.Row() if plan is not None and plan.chosen is not None else None
    record = {
        "scenario": scenario.plant_scene.name or "default",
        "station": "hardware" if world.hardware else "simulation",
        "method": scenario.planner.method,
        "energy_weight": scenario.planner.energy_weight,
        "perception": {"segmenter": scenario.perception.segmenter,
                       "camera": "device" if world.hardware else CameraProfile(
                           scenario.camera_noise)},
        "status": "aborted" if error else st.mode,
        "message": error or st.message,
        # ok | no_action_needed | no_fruit | no_feasible_action | stage_error
        "plan_status": "stage_error" if error.startswith("stage_error") else (
            plan.status if plan is not None else ("stage_error" if st.failed_stage else None)),
        "failed_stage": "diagram" if error.startswith("stage_error") else (
            st.failed_stage or None),
        "chosen_action": chosen,
        # Every executed motion: the plan's action, then the continuations
        # planned from the held leaf (``planner.max_replans``).
        "motions": [dict(p.chosen.Row(), predicted_visibility=(
            p.chosen.seen / p.seen_max if p.seen_max and p.chosen.seen >= 0 else None))
            for p in st.plans if p.chosen is not None][:len(st.motion_paths)],
        "replans": list(st.replan_log),
        # the force guard (planner.max_pull_force, max_retreat_force): the
        # largest rise of the wrist force above its value at each pre-grasp
        # pose while the leaf moved, and on the ways back out of the plant (N),
        # and every stop it made (when, the rise, which motion)
        "force_guard": {"limit_N": scenario.planner.max_pull_force,
                        "peak_N": max([st.force_peak] + [u.get("force_peak_N", 0.0)
                                                         for u in st.targets]),
                        "retreat_limit_N": scenario.planner.max_retreat_force,
                        "retreat_peak_N": st.retreat_peak,
                        "stops": list(st.force_stops),
                        "trace": [list(x) for x in st.force_trace]},
        # The planner's own visibility model (voxels of the estimated fruit):
        # seen initially, at most (fruit alone) and after the chosen action.
        "predicted_visibility": None if plan is None or not plan.seen_max else {
            "initial": plan.seen_init / plan.seen_max,
            "chosen": (plan.chosen.seen / plan.seen_max
                       if plan.chosen is not None and plan.chosen.seen >= 0 else None)},
        "outcome": None,
        "shape_initial": None,
        "shape_final": None,
        # the fruit's plausible shapes before and after the action (intervals
        # of volume, centre and axis; shape.ssc.num_hypotheses)
        "shape_hypotheses": {
            "initial": HypothesesRecord(getattr(st, "initial_estimate", None)),
            "final": HypothesesRecord(getattr(st, "final_estimate", None))},
        "stage_seconds": st.stage_seconds,
        "simulated_seconds": world.time,
        "simulation_wall_seconds": step_wall,
        "mode_wall_seconds": {k: round(v, 2) for k, v in mode_wall.items()},
        "wall_seconds": None,
        "mode_log": st.mode_log,
    }
    world.Score(record, views, st)
    record["wall_seconds"] = time.perf_counter() - wall0
    return EpisodeResult(record, world, before, after, st, views)


# Station seconds an episode may take per fruit of the plant (an episode
# with one reveal takes 15-30 s; a fruit under two leaves revealed by each
# about twice that).
SECONDS_PER_FRUIT = 60.0
# Fruits assumed on hardware with ``planner.targets: all``, where the plant's
# fruit count is not known before the first view.
HARDWARE_MAX_FRUITS = 4


def EpisodeTimeLimit(scenario: Scenario, per_fruit: float = SECONDS_PER_FRUIT) -> float:
    """Station seconds after which ``RunEpisode`` stops waiting for the
    controller: ``per_fruit`` times the simulated plant's fruit count
    (``plant_scene.multi.fruits``; 1 for a one-fruit plant), or times
    ``HARDWARE_MAX_FRUITS`` on a plant of unknown fruit count handled
    fruit by fruit (``planner.targets: all`` and no simulated multi-fruit
    plant)."""
    if scenario.plant_scene.kind in MULTI_KINDS:
        return per_fruit * max(1, NumPlantFruits(scenario.plant_scene))
    if scenario.planner.targets == "all":
        return per_fruit * HARDWARE_MAX_FRUITS
    return per_fruit


def RunSimEpisode(scenario: Scenario, meshcat=None,
                  progress: Callable[[str], None] | None = None,
                  max_time: float = SECONDS_PER_FRUIT,
                  resources: EpisodeResources | None = None, plan_only: bool = False
                  ) -> EpisodeResult:
    """One full episode on the simulated plant world (no confirmation),
    given ``max_time`` station seconds per fruit (``EpisodeTimeLimit``)."""
    progress = progress or (lambda m: None)
    max_time = EpisodeTimeLimit(scenario, max_time)
    resources = resources or EpisodeResources.Make(scenario, progress)
    resources.progress = progress
    world = SimWorld(scenario, resources, ControllerOptionsFor(scenario, False, plan_only),
                     meshcat, progress)
    return RunEpisode(scenario, world, progress, max_time)


def ConsoleConfirm(plan) -> tuple[bool, str]:
    """Shows the chosen action and asks the operator to type ``yes``."""
    print(f"[lmap-drake] chosen action: {DescribePlan(plan)}", flush=True)
    try:
        answer = input("[lmap-drake] move the robot to execute it? type 'yes' to move: ")
    except EOFError:
        return False, "no answer (end of input)"
    answer = answer.strip().lower()
    return (answer == "yes"), (f"answered {answer!r}" if answer != "yes" else "")


def RunLmapEpisode(scenario: Scenario, out: Path, progress: Callable[[str], None] = print,
                   hardware: bool = False, plan_only: bool = False, confirm: bool = False,
                   confirm_fn: Callable | None = None, clients=None,
                   realtime_rate: float | None = None,
                   resources: EpisodeResources | None = None
                   ) -> tuple[list[str], str]:
    """The full LMAP loop on the simulated station (the FEM plant world) or
    the hardware station (``clients`` injected, e.g. the project's fakes, or
    connected here), paced at ``realtime_rate`` station seconds per wall
    second (None: 1, or the digital twin's pace). Writes ``scenario.yaml`` (as run:
    on hardware with the device's intrinsics and the calibrated pose),
    ``episode.json``, ``plan.json``, ``candidates.json``, ``recording/``, images,
    figures, ``diagram.svg``, and in simulation the ground truth, ``outcome.json``
    and ``scene.html``. Returns (files, status: done | planned | aborted ...).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    confirm_fn = confirm_fn or ConsoleConfirm
    meshcat = None
    own = False
    if hardware:
        scenario, clients, own = PrepareHardware(scenario, clients, read_only=plan_only,
                                                 progress=progress)
    files = ["scenario.yaml"]
    world = None
    try:
        DumpScenario(scenario, out / "scenario.yaml")
        progress("loading the shape template, building the diagram")
        resources = resources or EpisodeResources.Make(scenario, progress)
        resources.progress = progress
        if hardware:
            q0, _ = clients.ur.ReadState()
            opts = ControllerOptionsFor(scenario, True, plan_only, confirm, initial_q=q0,
                                        initial_gripper=clients.gripper.Opening())
            if realtime_rate is None:    # a digital twin's camera tells its pace
                realtime_rate = float(getattr(clients.camera, "time_scale", 1.0))
                if realtime_rate != 1.0:
                    progress(f"running at {realtime_rate:g} station seconds per wall second "
                             f"(the twin's pace)")
            world = HardwareWorld(scenario, resources, opts, clients, read_only=plan_only,
                                  realtime_rate=realtime_rate, progress=progress)
        else:
            meshcat = Meshcat()
            opts = ControllerOptionsFor(scenario, False, plan_only, confirm)
            world = SimWorld(scenario, resources, opts, meshcat, progress)
            if getattr(world.model, "occlusion_clamped", False):
                m = world.model
                progress(f"warning: the leaf hides at most {m.occlusion_predicted:.2f} of the "
                         f"fruit, not the requested plant_scene.occlusion "
                         f"{m.occlusion_requested:.2f} (clamped; recorded in episode.json)")
            FrameMeshcat(meshcat, scenario)
            meshcat.StartRecording()
        # A plant with several fruits gets its time per fruit, as in `eval`
        # (a fixed 60 s cut a two-fruit `run` short while it was releasing
        # a leaf).
        result = RunEpisode(scenario, world, progress, EpisodeTimeLimit(scenario),
                            confirm=confirm_fn)
    finally:
        if world is not None:
            world.Close()
        elif hardware and own:
            clients.Close()
    if meshcat is not None:
        meshcat.StopRecording()
        meshcat.PublishRecording()
    files += SaveEpisode(result, out, clients if hardware else None)
    if not hardware and hasattr(world.model, "leaves"):
        files += SaveMultiGroundTruth(world.model, out)
    elif not hardware:
        files += SaveGroundTruth(world.model, out)
    files.append("diagram.svg" if WriteDiagramSvg(world.diagram, out / "diagram.svg")
                 else "diagram.dot")
    if meshcat is not None:
        (out / "scene.html").write_text(meshcat.StaticHtml())
        files.append("scene.html")
    r = result.record
    progress(f"episode {r['status']}: {r['message'] or '(no message)'}")
    if r["outcome"] is not None:
        progress(OutcomeLine(r["outcome"]))
    if r["shape_initial"] and r["shape_final"]:
        progress(f"Chamfer {r['shape_initial']['chamfer_cm']:.2f} cm -> "
                 f"{r['shape_final']['chamfer_cm']:.2f} cm; wall {r['wall_seconds']:.0f} s")
    return files, str(r["status"])
