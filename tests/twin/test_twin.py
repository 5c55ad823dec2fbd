"""Hardware in the loop without a robot: the real ``ur_rtde`` client (this
test process) against the digital twin (``lmap-drake twin`` in a child
process: the UR controller EMULATOR, the Robotiq socket and the camera
socket over the FEM plant world). One full episode, and one with a
protective stop injected by the twin mid-pull."""
import json
import random
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

pytest.importorskip("rtde_control", reason="the twin test needs ur_rtde (the test extra)")

from lmap_drake.episode import RunLmapEpisode, RunSimEpisode  # noqa: E402
from lmap_drake.paths import DEFAULT_SCENARIO_FILE  # noqa: E402
from lmap_drake.twin.twin import Twin, TwinOptions, TwinRunOverrides  # noqa: E402
from lmap_drake.scenario import LoadScenario  # noqa: E402

# The twin runs in real time: on a starved machine it catches up in bursts,
# which read as wrist force (the retreat peaked at 5.9 N beside two busy
# processes, 3.9 N alone). ``make test`` runs these alone, after the rest.
pytestmark = pytest.mark.realtime

PORTS = (29999, 30003, 30004, 63352, 50410)
RUN = "{hardware: {ur: {joint_speed_limit: 3.0}}}"     # faster moves: less twin time


def _FreeHost() -> str:
    for n in random.sample(range(20, 250), 20):
        host = f"127.0.0.{n}"
        try:
            for port in PORTS:
                with socket.socket() as s:
                    s.bind((host, port))
            return host
        except OSError:
            continue
    pytest.skip("no loopback address with the UR ports free")


class TwinProcess:
    """``lmap-drake twin`` in a child process, stopped with ``quit``."""

    def __init__(self, out, *args):
        self.host, self.out = _FreeHost(), out
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "lmap_drake.cli", "twin", "--host", self.host,
             "--output", str(out), "--duration", "900", *args],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        self.lines = []
        t_end = time.time() + 180
        while time.time() < t_end:
            line = self.proc.stdout.readline()
            if not line:
                break
            self.lines.append(line)
            if "lmap-drake run --hardware" in line:
                return
        self.proc.kill()
        raise AssertionError("the twin did not start:\n" + "".join(self.lines))

    def Stop(self) -> tuple[dict, dict]:
        self.proc.stdin.write("quit\n")
        self.proc.stdin.flush()
        rest, _ = self.proc.communicate(timeout=120)
        assert self.proc.returncode == 0, "".join(self.lines) + rest
        return (json.loads((self.out / "outcome.json").read_text()),
                json.loads((self.out / "twin_log.json").read_text()))

    def Scenario(self, *extra: str):
        opts = TwinOptions(host=self.host)
        text = TwinRunOverrides(opts, str(self.out / "calibration.yaml"))
        return LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name="Defaults",
                            scenario_text=[text, RUN, *extra])


@pytest.fixture(scope="module")
def twin_episode(tmp_path_factory):
    out = tmp_path_factory.mktemp("twin")
    twin = TwinProcess(out / "twin")
    try:
        files, status = RunLmapEpisode(twin.Scenario(), out / "run", progress=print,
                                       hardware=True)
    finally:
        outcome, log = twin.Stop()
    record = json.loads((out / "run" / "episode.json").read_text())
    return status, record, outcome, log, twin.Scenario()


def test_real_ur_rtde_runs_a_full_safe_episode_against_the_twin(twin_episode):
    status, record, outcome, log, _ = twin_episode
    assert status == "done", record["message"]
    assert [m for _, m in record["mode_log"]][-3:] == ["release", "retreat", "done"]
    assert not (outcome["leaf_damage"] or outcome["plant_hazard"] or outcome["fruit_collision"])
    assert outcome["visibility_final"] > outcome["visibility_initial"] + 0.3
    # The arm followed the plan: the twin made its grasp with the TCP within
    # 1 cm of the chosen grasp point, and released the leaf afterwards.
    events = [e["event"] for e in log["events"]]
    assert events.index("grasp") < events.index("release")
    p_grasp = np.array(next(e["p_WT"] for e in log["events"] if e["event"] == "grasp"))
    assert np.linalg.norm(p_grasp - record["chosen_action"]["p_WG"]) < 0.01
    assert log["emulator"]["ticks"] > 0


def test_the_twin_sees_what_the_simulation_sees(twin_episode):
    """The planner on the twin chose the action of the simulated run of the
    same scenario (plan only; hardware perception settings)."""
    _, record, *_ = twin_episode
    s = LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name="Defaults",
                     scenario_text="{perception: {no_return_free_range: 0.0}}")
    sim = RunSimEpisode(s, plan_only=True).record
    keys = ("grasp_id", "direction_id", "distance")
    assert [sim["chosen_action"][k] for k in keys] == \
        [record["chosen_action"][k] for k in keys]


def test_a_protective_stop_mid_pull_stops_the_run_with_the_gripper_holding(tmp_path):
    """A straight pull (an arc turns the wrist faster). How fast the
    simulated arm settles after the stop is the plant's property, not the
    controller's: 0.04-0.10 s measured on the grasp of the 8 cm ready pose,
    0.08-0.14 s on grasp 14 (2 cm ready pose, the default since the
    fallback), in 20 ms twin steps. A pull that went on would take seconds."""
    twin = TwinProcess(tmp_path / "twin", "--fault_after_grasp_move", "0.01")
    try:
        _, status = RunLmapEpisode(twin.Scenario("{planner: {action_families: [pull]}}"),
                                   tmp_path / "run", progress=print, hardware=True)
    finally:
        outcome, log = twin.Stop()
    record = json.loads((tmp_path / "run" / "episode.json").read_text())
    assert status == "aborted" and "protective stop" in record["message"], (record["message"],
                                                                             log["events"])
    assert [m for _, m in record["mode_log"]][-1] == "pull"
    events = [e["event"] for e in log["events"]]
    assert "protective_stop_injected" in events and "release" not in events
    # the arm stood still within 0.2 simulated s of the stop
    assert log["fault_stop"]["arm_stopped_after_s"] <= 0.2


def test_the_twin_gripper_reports_a_held_leaf_as_an_object():
    """The 2F-85's OBJ register over the simulated fingers: moving (0), at
    the request (3), stalled short of a closing request for 0.1 s (2), and
    2 whenever the plant world holds the leaf between the pads, even when
    the simulated fingers close past the request (the leaf hangs from them).
    The hardware controller pulls only on OBJ 2."""
    from lmap_drake.station.hardware_config import HardwareConfig
    from lmap_drake.twin.gripper import TwinGripper
    g = TwinGripper(HardwareConfig().gripper, 0.085)
    g.Set({"ACT": 1, "GTO": 1})
    assert g.Get("OBJ") == 3
    from lmap_drake.station.hardware.robotiq_client import OpeningToPos
    g.Set({"POS": OpeningToPos(0.0015, HardwareConfig().gripper)})
    g.SetMeasured(0.02, -0.05, 1.0)
    assert g.Get("OBJ") == 0                                 # closing
    g.SetMeasured(0.005, 0.0, 1.05)
    g.SetMeasured(0.005, 0.0, 1.10)
    assert g.Get("OBJ") == 0                                 # still for 0.05 s only
    g.SetMeasured(0.005, 0.0, 1.16)
    assert g.Get("OBJ") == 2                                 # stalled on the leaf
    g.holding = True
    g.SetMeasured(0.0, -0.02, 1.2)                           # past the request, holding
    assert g.Get("OBJ") == 2
    g.holding = False
    g.SetMeasured(0.0015, 0.0, 1.3)
    assert g.Get("OBJ") == 3                                 # at the request: nothing held


def test_the_twin_gripper_holding_never_reads_wider_than_where_it_met_the_leaf():
    """Simulated fingers that bounce open off the held leaf read as standing
    where the pads met it (a 2F-85 stopped on an object stays there), so the
    controller's hold request (just inside the reading) keeps the leaf."""
    from lmap_drake.station.hardware_config import HardwareConfig
    from lmap_drake.station.hardware.robotiq_client import OpeningToPos, PosToOpening
    from lmap_drake.twin.gripper import TwinGripper
    cfg = HardwareConfig().gripper
    g = TwinGripper(cfg, 0.085)
    g.Set({"ACT": 1, "GTO": 1, "POS": OpeningToPos(0.0, cfg)})
    g.held_at, g.holding = OpeningToPos(0.005, cfg), True
    g.SetMeasured(0.0087, 0.05, 1.0)                         # bounced open
    assert g.Get("OBJ") == 2 and PosToOpening(g.Get("POS"), cfg) <= 0.005 + 1e-9
    g.SetMeasured(0.002, -0.05, 1.02)                        # closed past it: as measured
    assert PosToOpening(g.Get("POS"), cfg) == pytest.approx(0.002, abs=0.0004)
    g.holding = False
    g.SetMeasured(0.0087, 0.0, 1.04)                         # let go: as measured again
    assert PosToOpening(g.Get("POS"), cfg) == pytest.approx(0.0087, abs=0.0004)


class _BlockedArmTwin(Twin):
    """TEST DOUBLE: a twin whose simulated arm is blocked (it stands for an
    arm held by an obstacle): its joint command stays ``blocked_q`` whatever
    the emulator commands; the simulation, the emulator and the shared
    state are the real ones."""
    blocked_q = None

    def _ArmCommand(self):
        return self.blocked_q


# The real ur_rtde client, in its own process (it holds the GIL while it waits).
_CLIENT = r"""
import json, sys, time
import rtde_control, rtde_receive
host, goal = sys.argv[1], json.loads(sys.argv[2])
receive = rtde_receive.RTDEReceiveInterface(host)
control = rtde_control.RTDEControlInterface(host)
before = receive.getActualQ()
ok = control.moveJ(goal, 0.5, 1.0)
time.sleep(1.5)
print(json.dumps({"ok": ok, "before": before, "after": receive.getActualQ(),
                  "target": receive.getTargetQ()}))
control.stopScript()
"""


def test_a_blocked_simulated_arm_shows_in_getactualq():
    """getActualQ follows the simulated arm, not the emulator's servo model:
    with the twin's simulated UR5 blocked at its start pose, a moveJ of the
    real ur_rtde client runs to its goal in the emulator (getTargetQ) while
    getActualQ stays at the simulated arm's blocked joints."""
    host = _FreeHost()
    scenario = LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name="Defaults")
    twin = _BlockedArmTwin(scenario, TwinOptions(host=host))
    twin.blocked_q = np.asarray(scenario.robot.initial_q, float)
    stop, thread = threading.Event(), None
    try:
        twin.Start()
        thread = threading.Thread(target=twin.Run, args=(stop,), daemon=True)
        thread.start()
        goal = twin.blocked_q + np.array([0.15, -0.1, 0.1, 0.0, 0.0, 0.1])
        run = subprocess.run([sys.executable, "-c", _CLIENT, host, json.dumps(goal.tolist())],
                             capture_output=True, text=True, timeout=180)
        assert run.returncode == 0, run.stderr[-2000:]
        got = json.loads(run.stdout.strip().splitlines()[-1])
    finally:
        stop.set()
        if thread is not None:
            thread.join(timeout=30)
        twin.Close()
    q_sim = twin.world.q()          # (the loop stopped: its context is free)
    assert got["ok"] and np.abs(np.subtract(got["target"], goal)).max() < 1e-3
    assert twin.world.time > twin.options.start_time + 0.5     # the simulation ran
    # the simulated arm stayed where it was blocked, and getActualQ with it
    assert np.abs(q_sim - twin.blocked_q).max() < 0.01
    assert np.abs(np.subtract(got["after"], q_sim)).max() < 0.005
    assert np.abs(np.subtract(got["after"], goal)).max() > 0.09
    # the loop's ground-truth samples: every outcome.sample_period on average
    # (as a simulated episode's), not every 0.02 s step
    t = np.array([s.t for s in twin.world.samples if s.t > twin.options.start_time + 1e-6])
    period = scenario.plant_scene.outcome.sample_period
    assert len(t) > 10 and np.diff(t).max() <= period + 0.02 + 1e-6
    assert np.diff(t).mean() == pytest.approx(period, abs=0.005)


def _Request(twin) -> float:
    """One camera request served by the twin's loop; the frame's time."""
    done, box = threading.Event(), {}
    twin._requests.put((done, box))
    twin._ServeFrames()
    assert done.is_set() and "error" not in box, box
    return box["frame"][0]


def test_the_twin_renders_seldom_while_the_arm_moves_and_at_once_at_rest():
    """A camera request while the arm or the fingers move gets the last
    frame until ``moving_frame_period`` passed (rendering with the camera
    model is most of the held phase's cost); once they stand still, a scene
    that moved since is rendered at the next request (the episode captures
    its views at rest)."""
    scenario = LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name="Defaults")
    twin = Twin(scenario, TwinOptions(frame_period=0.2, moving_frame_period=1.0))
    w = twin.world
    w.AdvanceTo(0.1)
    assert _Request(twin) == pytest.approx(0.1)
    w.AdvanceTo(0.5)
    twin._frame_pose = twin._frame_pose + 1.0       # the scene moved since that frame
    twin._moving = True
    assert _Request(twin) == pytest.approx(0.1)     # 0.4 s < 1 s: the last frame
    twin._moving = False
    assert _Request(twin) == pytest.approx(0.5)     # at rest: rendered now
    w.AdvanceTo(0.6)
    assert _Request(twin) == pytest.approx(0.5)     # 0.1 s < frame_period
    twin._frame_pose = twin._frame_pose + 1.0
    twin._moving = True
    w.AdvanceTo(1.6)
    assert _Request(twin) == pytest.approx(1.6)     # moving, but 1.1 s > 1 s
    assert [f["t"] for f in twin.frames] == pytest.approx([0.1, 0.5, 1.6])
