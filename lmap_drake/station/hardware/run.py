"""``lmap-drake run --hardware [--dry-run]``: one run on the real cell.

The full LMAP loop is not built yet, so a hardware run does what the
simulated ``run`` does: it moves the arm from where it is to
``robot.initial_q`` (a joint-space cubic at half the configured joint speed
limit, checked sample by sample by ``SafetyChecker``), opens the gripper to
``robot.initial_gripper_width``, holds for ``simulation_duration`` s, and
saves one RGB-D frame.

``--dry-run`` connects read-only (RTDE receive interface only: no control
script is uploaded; the gripper is not activated), reads the arm and
gripper state and one RGB-D frame, plans the same trajectory, checks it,
prints it, and writes it; nothing is commanded.

Files written to the output folder: ``scenario.yaml``, ``rgb.png``,
``depth.png``, ``hardware_state.yaml`` (joint state, gripper opening,
camera serial, intrinsics, depth scale, X_WC), ``trajectory.csv`` (t, q0..q5).
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np
import yaml
from pydrake.systems.analysis import ApplySimulatorConfig, Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from lmap_drake.scenario import DumpScenario, Scenario
from lmap_drake.station.hardware.safety import SafetyChecker
from lmap_drake.station.hardware_config import CalibrationError, CheckCalibrationSerial
from lmap_drake.station.hardware.station import (CheckHardwareSetup, ConnectHardwareClients,
                                                 HardwareClients,
                                                 MakeHardwareStation, StopHardwareStation)
from lmap_drake.viz import SaveDepth, SaveRgb


def PlanHomeTrajectory(q_start, q_goal, speed: float, hold: float) -> PiecewisePolynomial:
    """Joint-space cubic from ``q_start`` to ``q_goal`` with zero end
    velocities and peak joint speed ``speed`` (rad/s), then ``hold`` s at
    ``q_goal``."""
    q_start = np.asarray(q_start, dtype=float)
    q_goal = np.asarray(q_goal, dtype=float)
    dq = float(np.max(np.abs(q_goal - q_start)))
    T = max(1.5 * dq / speed, 0.5)  # a cubic's peak speed is 1.5 x its mean
    breaks = [0.0, T, T + max(hold, 1e-3)]
    samples = np.column_stack([q_start, q_goal, q_goal])
    return PiecewisePolynomial.CubicHermite(breaks, samples, np.zeros_like(samples))


def SampleTrajectory(traj: PiecewisePolynomial, period: float) -> tuple[np.ndarray, np.ndarray]:
    times = np.arange(traj.start_time(), traj.end_time() + 0.5 * period, period)
    times = np.minimum(times, traj.end_time())
    return times, np.array([traj.value(t).ravel() for t in times])


def FormatTrajectory(times, qs, every: float = 0.5) -> str:
    lines = [f"{'t (s)':>7}  " + "  ".join(f"q{i} (rad)" for i in range(6))]
    last = -np.inf
    for k, (t, q) in enumerate(zip(times, qs)):
        if t - last >= every - 1e-9 or k == len(times) - 1:
            lines.append(f"{t:7.2f}  " + "  ".join(f"{v:8.4f}" for v in q))
            last = t
    return "\n".join(lines)


def _WriteSnapshot(out: Path, clients: HardwareClients, q, v, opening, rgba, depth, X_WC,
                   times, qs) -> list[str]:
    SaveRgb(rgba, out / "rgb.png")
    SaveDepth(depth, out / "depth.png")
    cam = clients.camera
    info = cam.CameraInfo()
    state = {
        "ur5_q": [float(x) for x in q], "ur5_v": [float(x) for x in v],
        "gripper_opening": float(opening),
        "camera": {"serial": str(getattr(cam, "serial", "")),
                   "width": info.width(), "height": info.height(),
                   "fx": info.focal_x(), "fy": info.focal_y(),
                   "cx": info.center_x(), "cy": info.center_y(),
                   "depth_scale": float(getattr(cam, "depth_scale", float("nan")))},
        "X_WC": X_WC.GetAsMatrix4().tolist(),
    }
    (out / "hardware_state.yaml").write_text(yaml.safe_dump(state, sort_keys=False))
    np.savetxt(out / "trajectory.csv", np.column_stack([times, qs]), delimiter=",",
               header="t,q0,q1,q2,q3,q4,q5", comments="", fmt="%.6f")
    return ["rgb.png", "depth.png", "hardware_state.yaml", "trajectory.csv"]


def RunHardwareSnapshot(scenario: Scenario, out: Path, dry_run: bool = False,
                        progress: Callable[[str], None] = print,
                        clients: HardwareClients | None = None) -> list[str]:
    """One hardware run (see the module docstring). ``clients`` may be
    injected (tests); otherwise the real devices are connected. Raises
    HardwareStationUnavailable, SafetyRefusal or HardwareAbort."""
    out = Path(out)
    config = scenario.hardware
    own = clients is None
    calib, X_WC = CheckHardwareSetup(scenario, own)
    DumpScenario(scenario, out / "scenario.yaml")
    files = ["scenario.yaml"]
    if own:
        progress(f"connecting to the UR5 at {config.ur.robot_ip}"
                 + (" (read-only: dry run)" if dry_run else ""))
        clients = ConnectHardwareClients(config, read_only=dry_run)
    station = None
    try:
        try:   # a calibration made for another camera is refused before anything moves
            CheckCalibrationSerial(calib, getattr(clients.camera, "serial", ""),
                                   config.camera.calibration_file)
        except CalibrationError as err:
            from lmap_drake.station.station import HardwareStationUnavailable
            raise HardwareStationUnavailable(f"hardware station: {err}") from err
        q, v = clients.ur.ReadState()
        opening = clients.gripper.Opening()
        progress(f"UR5 q = {np.round(q, 4).tolist()} rad; gripper opening {opening:.4f} m")
        rgba, depth = clients.camera.Capture()
        checker = SafetyChecker(config.ur)
        speed = 0.5 * config.ur.joint_speed_limit
        traj = PlanHomeTrajectory(q, scenario.robot.initial_q, speed,
                                  scenario.simulation_duration)
        times, qs = SampleTrajectory(traj, config.ur.command_period)
        files += _WriteSnapshot(out, clients, q, v, opening, rgba, depth, X_WC, times, qs)
        progress(f"plan: measured q -> robot.initial_q in {traj.end_time() - scenario.simulation_duration:.2f} s "
                 f"(peak joint speed {speed:.3f} rad/s), then hold {scenario.simulation_duration:.2f} s; "
                 f"gripper -> {scenario.robot.initial_gripper_width:.4f} m "
                 f"(placeholder plan: the LMAP planner is not built yet)")
        checker.CheckTrajectory(times, qs)  # raises SafetyRefusal before anything moves
        progress(f"safety checks passed on {len(times)} samples")
        if dry_run:
            print(FormatTrajectory(times, qs), flush=True)
            progress("dry run: nothing was commanded")
            return files
        station = MakeHardwareStation(scenario, clients)
        builder = DiagramBuilder()
        builder.AddNamedSystem("station", station)
        q_src = builder.AddNamedSystem("ur5_plan", TrajectorySource(traj))
        builder.Connect(q_src.get_output_port(), station.GetInputPort("ur5.position"))
        grip = builder.AddNamedSystem(
            "gripper_hold", ConstantVectorSource([scenario.robot.initial_gripper_width]))
        builder.Connect(grip.get_output_port(), station.GetInputPort("gripper.position"))
        diagram = builder.Build()
        simulator = Simulator(diagram)
        ApplySimulatorConfig(scenario.simulator_config, simulator)
        simulator.set_target_realtime_rate(1.0)  # periodic events stand for wall time
        progress(f"executing {traj.end_time():.2f} s on the robot")
        simulator.AdvanceTo(traj.end_time())
        context = station.GetMyContextFromRoot(simulator.get_context())
        SaveRgb(station.GetOutputPort("camera0.rgb_image").Eval(context), out / "rgb.png")
        SaveDepth(station.GetOutputPort("camera0.depth_image").Eval(context), out / "depth.png")
        return files
    finally:
        if station is not None:
            StopHardwareStation(station)
        elif own:
            clients.Close()
