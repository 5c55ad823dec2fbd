"""The digital twin (``lmap-drake twin``): the simulated plant world behind
the hardware protocols, so that ``lmap-drake run --hardware`` with the real
``ur_rtde`` client runs a whole LMAP episode without a robot, and the plant
world scores it. The episode runs in another process (ur_rtde holds the GIL
while it waits for its controller). The twin runs:

- the UR controller EMULATOR (``twin.ur_emulator``, a child process, so its
  500 Hz loop never waits for the simulation) on ``host`` (dashboard 29999,
  RTDE 30004, script 30003) for the real ur_rtde client: its servo model's
  joints are the simulated UR5's command; the simulated UR5's measured
  joints and wrist force are what it reports (``getActualQ``: a blocked
  arm shows; ``getActualTCPForce``), through shared memory every 20 ms;
- the Robotiq URCap socket (``twin.robotiq_server``, ``gripper_port``) over
  a register model whose fingers are the simulated 2F-85's (they stall on
  the FEM leaf);
- camera frames rendered from the plant world (``twin.camera_server``,
  ``camera_port``), with the scenario's camera model;
- the grasp as in simulation: when the pads close on the leaf the station is
  rebuilt with the leaf fixed between them, and undone when they open.

The plant world advances at ``rate`` simulated s per wall s (default 0.5;
not real time on 2 cores while it holds the leaf); the camera tells the
episode runner that pace so both share one clock. A frame is rendered again
only when the arm, the fingers or the leaf moved, at most every
``frame_period`` simulated s, and every ``moving_frame_period`` while the
arm or the fingers move; while the leaf is held the plant steps
``held_time_step``. Ground-truth samples are taken every
``outcome.sample_period``; ``Finish`` writes ``outcome.json`` (up to the
release, ``release_outcome`` after it) and ``twin_log.json`` (events,
pacing: ``pace``, ``max_lag_s``, ``timing`` (wall s by phase and kind of
work, the process's CPU s), the emulator's loop statistics).
"""
from __future__ import annotations

import copy
import dataclasses as dc
import json
import queue
import threading
import time
from pathlib import Path
from typing import Callable

import numpy as np
from pydrake.trajectories import PiecewisePolynomial

from lmap_drake.errors import InputError
from lmap_drake.perception.points import Intrinsics
from lmap_drake.plants.outcome import Summarize
from lmap_drake.plants.plant_sim import PlantWorldSim
from lmap_drake.plants.plant_station import MakePlantStation
from lmap_drake.scenario import Scenario
from lmap_drake.station.hardware.robotiq_client import OpeningToPos
from lmap_drake.station.hardware_config import CameraCalibration
from lmap_drake.twin.camera_server import TwinCameraServer
from lmap_drake.twin.gripper import TwinGripper
from lmap_drake.twin.robotiq_server import RobotiqSocketServer
from lmap_drake.twin.ur_emulator import EmulatorProcess


STILL = 1e-4     # m or rad: a scene that moved less is rendered again only as a copy
MOVING_RAD_S = 0.01     # an arm joint faster than this (rad/s) moves
MOVING_M_S = 0.001      # fingers faster than this (m/s) move


@dc.dataclass
class TwinOptions:
    """Where the twin listens and how fast it runs."""
    host: str = "127.0.0.1"
    camera_port: int = 50410
    gripper_port: int = 63352
    rate: float = 0.5                 # simulated s per wall s
    # re-render at most every this many simulated s (the run command's camera fps 5:
    # a twin behind its clock got requests faster and rendered more, falling further behind)
    frame_period: float = 0.2
    # ... every this many while the arm or the fingers move (the episode captures its
    # views at rest; a frame costs 0.2-0.35 s CPU, most of it the camera model's noise)
    moving_frame_period: float = 1.0
    sample_period: float = 0.0    # ground-truth samples (0: outcome.sample_period)
    # The plant's time step (s) while the pads hold the leaf (the station with the
    # grasp constraint; 0: the scenario's plant_config.time_step): the FEM leaf's
    # step is most of the twin's work then. The free station keeps the scenario's.
    held_time_step: float = 0.02
    # FEM threads (0: plant_scene.fem_threads): the twin shares its cores with the runner;
    # 2 threads on a loaded 2-core machine doubled the CPU per simulated s (same results)
    fem_threads: int = 1
    fault: str = "protective_stop"       # protective_stop | emergency_stop | drop
    fault_after_grasp_move: float = 0.0  # > 0: inject ``fault`` once the held leaf moved (m)
    # The plant settles to this time (when a simulated episode captures its
    # first view), then the clock waits for the arm's first motion: the
    # frames the planner sees are those of the simulated run.
    start_time: float = 0.31
    allow_remote: bool = False        # listen on a host that is not loopback (a warning)
    log_dir: str = ""                 # the UR emulator's log goes here ("": a temp file)


class _EmulatorChild:
    """The UR controller emulator in a child process (``EmulatorProcess``):
    its 500 Hz loop then never waits for the simulation's Python work (the
    GIL). The arm's state crosses in shared memory (``SharedArmState``, no
    pipe round trip per step): ``Exchange`` hands the emulator the
    simulated arm's measured joints (its ``getActualQ``) and reads its servo
    model's joints (the command) and stop flags; ``Poll`` refreshes the full
    state (statistics, fault log) over the control pipe."""

    def __init__(self, host: str, q0, log_path: str | None = None, allow_remote: bool = False):
        self.proc = EmulatorProcess(host, q0=q0, shared_state=True, log_path=log_path,
                                    allow_remote=allow_remote)
        self.state = self.proc.State()
        self._servo = (np.asarray(self.state["q_servo"], float), False, False)
        self.Exchange()

    def Poll(self) -> None:
        self.state = self.proc.State()

    def Exchange(self, q_measured=None, v_measured=None, tcp_force=(0.0, 0.0, 0.0)) -> None:
        """Writes the simulated arm's joints (rad, rad/s; None: none yet) and
        wrist force (N) and reads the emulator's servo joints and stop flags."""
        if q_measured is not None:
            self.proc.shared.WriteMeasured(q_measured, v_measured, tcp_force)
        servo = self.proc.shared.ReadServo()
        if servo is not None:
            self._servo = servo

    @property
    def q_servo(self) -> np.ndarray:
        """The emulator's servo model joints (rad): the simulated arm's command."""
        return np.array(self._servo[0], float)

    @property
    def protective_stopped(self) -> bool:
        return self._servo[1]

    @property
    def emergency_stopped(self) -> bool:
        return self._servo[2]

    @property
    def stats(self) -> dict:
        return dict(self.state["stats"])

    @property
    def fault_log(self) -> list:
        return list(self.state["fault_log"])

    def Inject(self, fault: str) -> None:
        """``protective_stop``, ``emergency_stop`` or ``drop`` (every
        connection closed, new ones refused for 5 s)."""
        self.state = {"protective_stop": self.proc.ProtectiveStop,
                      "emergency_stop": self.proc.EmergencyStop,
                      "drop": lambda: self.proc.DropConnections(5.0)}[fault]()

    def Close(self) -> None:
        try:
            self.Poll()
        except Exception:  # noqa: BLE001 - keep the last state
            pass
        self.proc.Close()


class Twin:
    """See the module docstring. ``Start``, then ``Run`` (blocks until
    ``stop`` is set), then ``Finish(out)``."""

    def __init__(self, scenario: Scenario, options: TwinOptions | None = None,
                 progress: Callable[[str], None] | None = None):
        self.options = options or TwinOptions()
        if self.options.fem_threads > 0:
            scenario = copy.deepcopy(scenario)
            scenario.plant_scene.fem_threads = int(self.options.fem_threads)
        self.scenario = scenario
        self.progress = progress or (lambda m: None)
        self.world = PlantWorldSim(scenario, None, self.progress,
                                   make_diagram=self._StationMaker())
        self.gripper = TwinGripper(scenario.hardware.gripper, scenario.robot.initial_gripper_width)
        K = Intrinsics.FromCameraConfig(scenario.cameras["camera0"])
        self.camera_info = {"width": K.width, "height": K.height, "fx": K.fx, "fy": K.fy,
                            "cx": K.cx, "cy": K.cy, "serial": "twin",
                            "depth_scale": float("nan"), "time_scale": self.options.rate}
        self._requests: queue.Queue = queue.Queue()
        self._frame = None                     # (t, rgba, depth)
        self.events: list[dict] = []
        self.frames: list[dict] = []           # t, visibility of every rendered frame
        self.trace: list[dict] = []            # every 0.1 simulated s: commands and the world
        self.lag_max, self._payload_force = 0.0, None   # (N: the tool's weight, at the start)
        self.paced = {"simulated_s": 0.0, "wall_s": 0.0}   # from the first motion on
        # wall s by phase (leaf held or not) and kind of work, from the first motion on
        # (and ``cpu_s``: the process's CPU seconds, every thread)
        self.timing = {p: dict.fromkeys(("simulated_s", "advance", "render", "other", "idle",
                                         "cpu_s"), 0.0) for p in ("free", "held")}
        self.vis_initial = None
        self.release_sample = None
        self.vis_at_release = None
        self._grasp_tcp = None
        self._held_moved, self.vis_held = 0.0, None
        self._stall_since = None
        self._fault_t = None
        self.fault_stop: dict = {}
        self._grasp_tried_at = None
        self._grasp_opening = None      # where the pads met the leaf
        self.stopped_by_twin = False
        self._timing_on, self._booked, self._cpu_last = False, 0.0, 0.0
        self._frame_pose = None        # arm, fingers, leaf of the last rendered frame
        self._moving = False           # the arm or the fingers moved in the last step
        self.emulator = self.camera = self.gripper_server = None

    def _StationMaker(self):
        """``make_diagram`` for the plant world: the scenario's station, with
        ``held_time_step`` while a leaf is held."""
        held = self.scenario
        if self.options.held_time_step > 0:
            held = copy.deepcopy(self.scenario)
            held.plant_config.time_step = float(self.options.held_time_step)

        def make(scenario, meshcat, grasp):
            station = MakePlantStation(scenario if grasp is None else held, meshcat,
                                       leaf_grasp=grasp)
            return station, station
        return make

    # --- servers ------------------------------------------------------------
    def Start(self) -> "Twin":
        o = self.options
        try:
            log = str(Path(o.log_dir) / "ur_emulator.log") if o.log_dir else None
            self.emulator = _EmulatorChild(o.host, tuple(self.scenario.robot.initial_q), log,
                                           o.allow_remote)
            self.gripper_server = RobotiqSocketServer(self.gripper, o.host, o.gripper_port,
                                                      o.allow_remote)
            self.gripper_server.__enter__()
            self.camera = TwinCameraServer(self.camera_info, self._FrameRequest, o.host,
                                           o.camera_port, o.allow_remote).Start()
        except OSError as err:
            self.Close()
            raise InputError(f"twin: cannot listen on {o.host} ({err}); another twin or a "
                             f"UR emulator may be running there: use --host 127.0.0.2 or other "
                             f"ports") from None
        self.world.AdvanceTo(self.options.start_time)
        self._Measure()
        self.vis_initial = self.world.Visibility()
        return self

    def _Measure(self) -> np.ndarray:
        """The simulated arm's joints to the emulator (``getActualQ``) and its
        wrist force less the tool's weight (read at the start: a UR
        compensates its payload) as ``getActualTCPForce``; returns its
        joint speeds (rad/s)."""
        port, ctx = self.world.station.GetOutputPort, self.world.station_context
        state = port("ur5.state_estimated").Eval(ctx)
        f = np.asarray(port("ur5.wrist_force").Eval(ctx), float)
        if self._payload_force is None:
            self._payload_force = f.copy()
        self.emulator.Exchange(state[:6], state[6:], f - self._payload_force)
        return state[6:]

    def _FrameRequest(self):
        """Called by the camera server's threads: the main loop renders."""
        done = threading.Event()
        box = {}
        self._requests.put((done, box))
        if not done.wait(timeout=30.0):
            raise TimeoutError("the twin's simulation loop did not answer")
        if "error" in box:
            raise RuntimeError(box["error"])
        return box["frame"]

    def _ServeFrames(self) -> None:
        while True:
            try:
                done, box = self._requests.get_nowait()
            except queue.Empty:
                return
            try:
                t, o = self.world.time, self.options
                period = max(o.frame_period, o.moving_frame_period) if self._moving \
                    else o.frame_period
                if self._frame is None or (t - self._frame[0] >= period - 1e-9
                                           and not self._Still()):
                    t_render = time.perf_counter()
                    self._frame_pose = self._Pose()
                    images = self.world.Images()
                    rgba = np.array(images["rgb_image"].data, np.uint8)
                    depth = np.array(images["depth_image"].data[..., 0], np.float32)
                    self._frame = (t, rgba, depth)
                    vis = self.world.Visibility(images["label_image"])
                    self.frames.append({"t": t, "visibility": vis})
                    if self.world.grasp_state is not None:     # the held leaf's farthest view
                        moved = float(np.linalg.norm(self.world.X_WT().translation()
                                                     - self._grasp_tcp))
                        if moved >= self._held_moved - 1e-4:
                            self._held_moved, self.vis_held = moved, vis
                    self._Spent("render", time.perf_counter() - t_render)
                box["frame"] = self._frame
            except Exception as err:  # noqa: BLE001 - reported to the camera client
                box["error"] = f"{type(err).__name__}: {err}"
            done.set()

    def _Still(self) -> bool:
        """True when the arm, the fingers and the leaf moved less than
        ``STILL`` (m or rad) since the last rendered frame: that frame is
        served again (rendering with the camera model costs 0.1-0.3 s)."""
        last, pose = self._frame_pose, self._Pose()
        return last is not None and last.shape == pose.shape and \
            np.abs(pose - last).max() < STILL

    def _Pose(self) -> np.ndarray:
        w = self.world
        return np.concatenate([w.q(), [w.GripperWidth()], w.LeafVertices(0).ravel()])

    # --- the loop -----------------------------------------------------------
    def Run(self, stop: threading.Event, step: float = 0.02) -> None:
        """Waits for the arm's first motion (serving frames), then advances
        the plant world at ``rate`` until ``stop`` is set."""
        w = self.world
        self.emulator.Exchange()
        q0 = self.emulator.q_servo
        while not stop.is_set():       # the clock starts with the first motion
            self._ServeFrames()
            self.emulator.Exchange()
            if np.abs(self.emulator.q_servo - q0).max() > 1e-4 or (
                    self.gripper.RequestedOpening() not in (None, w.width_cmd)):
                self.events.append({"t": w.time, "event": "first_motion"})
                break
            time.sleep(0.02)
        self.RunPaced(stop, step)

    def RunPaced(self, stop: threading.Event, step: float = 0.02) -> None:
        """Advances the plant world at ``rate`` from now until ``stop`` is
        set (the pace and timing count from here)."""
        w, o = self.world, self.options
        last_width = w.GripperWidth()
        t0, wall0 = w.time, time.monotonic()
        sample_period = o.sample_period or self.scenario.plant_scene.outcome.sample_period
        next_sample = w.time
        self._timing_on, self._cpu_last = True, time.process_time()
        while not stop.is_set():
            self.paced = {"simulated_s": w.time - t0, "wall_s": time.monotonic() - wall0}
            self._SpentCpu()
            self._ServeFrames()
            ahead = t0 + (time.monotonic() - wall0) * o.rate - w.time
            if ahead < step:
                t_idle = time.perf_counter()
                time.sleep(min(0.02, (step - ahead) / o.rate))
                self._Spent("idle", time.perf_counter() - t_idle)
                continue
            self.lag_max = max(self.lag_max, ahead - step)
            t_step = time.perf_counter()
            self.emulator.Exchange()
            q_from, w.q_cmd = w.q_cmd.copy(), self._ArmCommand()
            opening = self.gripper.RequestedOpening()
            if opening is not None:
                w.width_cmd = float(opening)
            w.ApplyCommands()
            t_advance = time.perf_counter()
            # The servo's samples joined by straight lines at the plant's step (as a UR
            # interpolates servoj targets): held for the whole step, each new sample read
            # as a one-plant-step velocity spike, 3-6 N at the wrist backing out of the
            # default scene (0.3 N in the simulated run) and 10.1 N once on a loaded CI.
            ramp = PiecewisePolynomial.FirstOrderHold([w.time, w.time + step],
                                                      np.c_[q_from, w.q_cmd])
            w.AdvanceTo(w.time + step, q_traj=ramp, step=w.plant.time_step() or step,
                        sample=False)
            if w.time >= next_sample - 1e-9:
                w.samples.append(w.Sample())
                next_sample += sample_period      # the mean period, on the step grid
            self._Spent("advance", time.perf_counter() - t_advance)
            self.timing["held" if w.grasp_state is not None else "free"]["simulated_s"] += step
            v = self._Measure()
            width = w.GripperWidth()
            rate = (width - last_width) / step
            self._moving = bool(np.abs(v).max() > MOVING_RAD_S or abs(rate) > MOVING_M_S)
            self.gripper.SetMeasured(width, rate, w.time)
            last_width = width
            if not self.trace or w.time - self.trace[-1]["t"] >= 0.1 - 1e-9:
                self.trace.append({"t": w.time, "wall": time.monotonic() - wall0,
                                   "q_command": w.q_cmd.tolist(),
                                   "q": w.q().tolist(), "p_WT": w.X_WT().translation().tolist(),
                                   "opening_command": w.width_cmd, "opening": width})
            self._GraspAndRelease(width, rate)
            self._WatchFaults()
            self._Spent("other", time.perf_counter() - t_step)

    def _SpentCpu(self) -> None:
        """Books this process's CPU seconds (every thread: the loop, the
        FEM's threads, the servers) since the last call to the phase now."""
        cpu = time.process_time()
        phase = self.timing["held" if self.world.grasp_state is not None else "free"]
        phase["cpu_s"] += cpu - self._cpu_last
        self._cpu_last = cpu

    def _Spent(self, kind: str, seconds: float) -> None:
        """Books wall seconds (``other``: a whole step, less what was booked
        inside it)."""
        if not self._timing_on:
            return
        phase = self.timing["held" if self.world.grasp_state is not None else "free"]
        if kind == "other":
            seconds -= self._booked
            self._booked = 0.0
        elif kind == "advance":       # inside the step
            self._booked += seconds
        phase[kind] += seconds

    def _ArmCommand(self) -> np.ndarray:
        """The simulated arm's joint command (rad): the emulator's servo joints."""
        return self.emulator.q_servo

    def _GraspAndRelease(self, width: float, rate: float) -> None:
        """The pads hold the leaf once they close to ``grasp_attach_opening``
        or stall on it for 0.1 s short of a closing request (what the 2F-85
        reports as an object); they let go when asked to open 2 mm past the
        opening where they met the leaf (not past the measured one: once the
        leaf hangs from the pads, the simulated fingers may close past a
        request)."""
        w = self.world
        closing = w.width_cmd < width - 1e-4
        stalled = closing and width > w.width_cmd + 0.001 and abs(rate) < 0.005
        self._stall_since = (w.time if self._stall_since is None else self._stall_since) \
            if stalled else None
        stalled_long = stalled and w.time - self._stall_since >= 0.1 - 1e-9
        if w.grasp_state is None and closing and (
                width <= self.scenario.planner.grasp_attach_opening or stalled_long) and \
                self._grasp_tried_at != round(width, 4):
            try:
                w.Grasp()
                self.gripper.held_at = OpeningToPos(width, self.gripper.config)
                self.gripper.holding = True
                self._grasp_opening = width
                self._grasp_tcp = w.X_WT().translation()
                self.events.append({"t": w.time, "event": "grasp",
                                    "p_WT": self._grasp_tcp.tolist(),
                                    "opening": width})
                self.progress(f"twin: grasp made at t = {w.time:.2f} s")
            except RuntimeError as err:
                self._grasp_tried_at = round(width, 4)   # not again at the same opening
                self.events.append({"t": w.time, "event": "grasp_failed", "why": str(err)})
        elif w.grasp_state is not None and w.width_cmd > self._grasp_opening + 0.002:
            self.release_sample = len(w.samples)
            self.vis_at_release = w.Visibility()
            w.ApplyCommands()
            w.Release()
            self.gripper.holding = False
            w.ApplyCommands()
            self.events.append({"t": w.time, "event": "release", "opening_cmd": w.width_cmd,
                                "grasp_opening": self._grasp_opening})
            self.progress(f"twin: leaf released at t = {w.time:.2f} s")
        d, fault = self.options.fault_after_grasp_move, self.options.fault
        if d > 0 and w.grasp_state is not None and not self.stopped_by_twin and \
                np.linalg.norm(w.X_WT().translation() - self._grasp_tcp) >= d:
            self.stopped_by_twin = True
            self.emulator.Inject(fault)
            self._fault_t = w.time if self._fault_t is None else self._fault_t
            self.events.append({"t": w.time, "event": f"{fault}_injected"})
            self.progress(f"twin: {fault} injected at t = {w.time:.2f} s (held leaf moved "
                          f"{d} m)")

    def _WatchFaults(self) -> None:
        """Logs a protective or emergency stop (whoever caused it) and how
        long the simulated arm took to stand still after it (joint speeds
        under 0.01 rad/s)."""
        emu, w = self.emulator, self.world
        if self._fault_t is None and (emu.protective_stopped or emu.emergency_stopped):
            self._fault_t = w.time
            kind = "protective stop" if emu.protective_stopped else "emergency stop"
            self.events.append({"t": w.time, "event": kind})
        if self._fault_t is not None and "arm_stopped_after_s" not in self.fault_stop:
            v = w.station.GetOutputPort("ur5.state_estimated").Eval(w.station_context)[6:]
            if np.abs(v).max() < 0.01:
                self.fault_stop["arm_stopped_after_s"] = w.time - self._fault_t
                self.fault_stop["t_fault"] = self._fault_t
                self.events.append({"t": w.time, "event": "arm_stopped"})

    # --- results ------------------------------------------------------------
    def Finish(self, out: Path) -> dict:
        """Writes ``outcome.json`` and ``twin_log.json`` to ``out``."""
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        w, cfg = self.world, self.scenario.plant_scene.outcome
        cut = self.release_sample if self.release_sample is not None else len(w.samples)
        # the final visibility: in the frame where the held leaf was moved
        # farthest (the episode observes there, at the end of the pull)
        vis_final = next(v for v in (self.vis_held, self.vis_at_release, w.Visibility())
                         if v is not None)
        outcome = Summarize(w.samples[:cut], cfg, self.vis_initial, vis_final).to_dict()
        if self.release_sample is not None:
            after = Summarize(w.samples[cut:], cfg, vis_final, w.Visibility()).to_dict()
            outcome["release_outcome"] = {k: after[k] for k in (
                "plant_hazard", "fruit_collision", "max_petiole_force",
                "max_fruit_penetration", "max_fruit_contact_force")}
        (out / "outcome.json").write_text(json.dumps(outcome, indent=2))
        stats = dict(self.emulator.stats) if self.emulator is not None else {}
        log = {"events": self.events, "frames": self.frames, "trace": self.trace,
               "simulated_seconds": w.time,
               "rate": self.options.rate, "max_lag_s": self.lag_max,
               "pace": dict(self.paced, ratio=self.paced["simulated_s"]
                            / max(self.paced["wall_s"], 1e-9)),
               "fault_stop": self.fault_stop, "timing": self.timing,
               "emulator": stats,
               "emulator_faults": list(getattr(self.emulator, "fault_log", []))}
        (out / "twin_log.json").write_text(json.dumps(log, indent=1, default=float))
        return outcome

    def Close(self) -> None:
        for server, close in ((self.camera, "Close"), (self.emulator, "Close")):
            if server is not None:
                try:
                    getattr(server, close)()
                except Exception:  # noqa: BLE001
                    pass
        if self.gripper_server is not None:
            try:
                self.gripper_server.__exit__(None, None, None)
            except Exception:  # noqa: BLE001
                pass


def TwinRunOverrides(options: TwinOptions, calibration_file: str) -> str:
    """The ``--scenario_text`` that points ``lmap-drake run --hardware`` at
    the twin (a pedestal cell: the plant world's start pose has its wrists
    below the robot base plane)."""
    o = options
    return ("{hardware: {ur: {robot_ip: %s, workspace_min: [-0.85, -0.85, -0.2], "
            "joint_speed_limit: 1.5}, "
            "gripper: {host: %s, port: %d}, camera: {twin_address: '%s:%d', "
            "calibration_file: '%s', fps: 5}}}" % (o.host, o.host, o.gripper_port, o.host,
                                                    o.camera_port, calibration_file))


def WriteTwinCalibration(scenario: Scenario, path: Path) -> None:
    """The twin camera's pose as a calibration file (serial ``twin``; the
    scenario's own pose values, at full precision)."""
    from pydrake.common.yaml import yaml_dump_typed
    calib = CameraCalibration(X_WC=scenario.cameras["camera0"].X_PB, camera_serial="twin",
                              notes="the simulated camera0 of the twin's scenario")
    Path(path).write_text("# the digital twin's camera pose (written by lmap-drake twin)\n"
                          + yaml_dump_typed(calib))
