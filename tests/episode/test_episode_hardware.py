"""The episode runner on the hardware station, with the project's FAKE
clients (fake ur_rtde interfaces, a FakeRobotiqServer speaking the URCap
protocol on localhost, or a FakeModbusGripperServer, the same fake gripper
as a Modbus RTU slave on a pseudo-terminal, a fake pyrealsense2 serving a
render of the default plant world): the whole LMAP loop, plan-only, operator confirmation, an
abort in every state, Ctrl-C, and record -> replay. Nothing here talks to a
robot; the planner is made cheap (fewer grasps and directions, fewer SSC
iterations) and the fake cell runs unpaced (``realtime_rate=0``)."""
import copy
import json

import numpy as np
import pytest

from lmap_drake.diagram import EpisodeResources
from lmap_drake.episode import ConsoleConfirm, ReplayRun, RunLmapEpisode
from lmap_drake.paths import DEFAULT_SCENARIO_FILE
from lmap_drake.perception.points import Intrinsics
from lmap_drake.perception.recording import LoadRecording
from lmap_drake.scenario import LoadScenario
from fakes.hardware import (FakeGripper, FakePyrealsense2, FakeRobotiqServer,
                                               MakeFakeHardwareClients)
from fakes.modbus import FakeModbusGripperServer
from lmap_drake.station.hardware.robotiq_client import OpeningToPos
from lmap_drake.station.hardware.safety import TcpPositionInBase

# A pedestal cell: the default scene's start pose has its wrists 8 cm below
# the robot base plane, so the box floor is lowered for these tests.
CELL = ("{hardware: {camera: {calibration_file: diagrams/calibration_example.yaml, fps: 6}, "
        "ur: {workspace_min: [-0.85, -0.85, -0.2], joint_speed_limit: 3.0}}, "
        "planner: {num_grasps: 5, num_directions: 6, distances: [0.04, 0.06]}, "
        "shape: {ssc: {iterations: 100}}}")
LEAF_OPENING = 0.003      # where the fake fingers stall: the leaf between the pads


@pytest.fixture(scope="module")
def cell():
    """(scenario, frames, resources): the render the fake camera serves and
    the shared decoder/robot model."""
    from lmap_drake.plants.plant_station import RenderStill
    s = LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name="Defaults",
                     scenario_text=CELL)
    rgb, depth, _ = RenderStill(s)
    return s, (rgb, depth), EpisodeResources.Make(s)


class FakeCell:
    """Fake clients for one run plus a progress log and fault injection:
    ``inject[mode] = callable`` runs when the controller enters ``mode``."""

    def __init__(self, cell, read_only=False, leaf_opening=LEAF_OPENING, link="urcap_socket"):
        self.scenario, frames, self.resources = cell
        K = Intrinsics.FromCameraConfig(self.scenario.cameras["camera0"])
        self.rs = FakePyrealsense2(frames=frames, intrinsics=(K.fx, K.fy, K.cx, K.cy))
        self.gripper = FakeGripper(object_pos=None if leaf_opening is None else OpeningToPos(
            leaf_opening, self.scenario.hardware.gripper))
        self.link = link
        if link == "modbus_rtu":      # the 2F-85 over RS-485: a Modbus RTU slave on a pty
            self.server = FakeModbusGripperServer(self.gripper).__enter__()
            self.scenario = copy.deepcopy(self.scenario)
            self.scenario.hardware.gripper.link = "modbus_rtu"
            self.scenario.hardware.gripper.serial_device = self.server.device
        else:
            self.server = FakeRobotiqServer(self.gripper).__enter__()
        self.clients = MakeFakeHardwareClients(self.scenario.hardware,
                                               q0=self.scenario.robot.initial_q,
                                               gripper_server=self.server, rs=self.rs,
                                               read_only=read_only)
        self.log, self.inject, self.at_injection = [], {}, {}
        self.targets = {}         # mode -> last accepted UR target when it was entered

    def progress(self, msg: str) -> None:
        self.log.append(msg)
        mode = msg.split(":")[0]
        self.targets[mode] = self.clients.ur.last_target
        if mode in self.inject:
            self.at_injection = {"PRE": self.gripper.regs["PRE"], "sets": self.gripper_writes}
            self.inject.pop(mode)()

    def run(self, out, **kw):
        try:
            files, status = RunLmapEpisode(self.scenario, out, progress=self.progress,
                                           hardware=True, clients=self.clients,
                                           realtime_rate=0.0, resources=self.resources, **kw)
        finally:
            self.server.__exit__(None, None, None)
        self.record = json.loads((out / "episode.json").read_text())
        return files, status

    @property
    def gripper_writes(self) -> int:
        """Requests sent to the gripper so far (SET lines, or Modbus writes)."""
        if self.link == "modbus_rtu":
            return len(self.server.writes)
        return sum(r.startswith("SET") for r in self.server.received)

    @property
    def modes(self):
        return [m for _, m in self.record["mode_log"]]

    @property
    def servoed(self):
        return np.array(self.clients.ur.control.servoed_qs) if self.clients.ur.control else []


def _FullRun(cell, tmp_path_factory, link):
    fake = FakeCell(cell, link=link)
    out = tmp_path_factory.mktemp(f"hw_full_{link}")
    asked = []

    def yes(plan):
        asked.append(plan)
        return True, ""
    files, status = fake.run(out, confirm=True, confirm_fn=yes)
    return fake, out, files, status, asked


@pytest.fixture(scope="module")
def full_run(cell, tmp_path_factory):
    return _FullRun(cell, tmp_path_factory, "urcap_socket")


@pytest.fixture(scope="module")
def modbus_run(cell, tmp_path_factory):
    """The full episode with ``hardware.gripper.link: modbus_rtu``."""
    return _FullRun(cell, tmp_path_factory, "modbus_rtu")


@pytest.mark.parametrize("run", ["full_run", "modbus_run"])
def test_hardware_episode_runs_every_state_then_releases_and_retreats(request, run):
    fake, out, files, status, asked = request.getfixturevalue(run)
    assert status == "done", fake.record["message"]
    # The fake camera serves one still frame, so the fruit stays hidden after
    # the pull and the controller may plan further motions from the held
    # leaf (planner.max_replans), each asked for and observed again.
    r = fake.record
    n = len(r["motions"]) - 1
    assert 0 <= n <= fake.scenario.planner.max_replans, r["motions"]
    assert fake.modes == (["capture", "plan_requested", "confirm_wait", "pregrasp", "approach",
                           "close_gripper", "grasp_wait", "pull", "hold", "observe"]
                          + ["confirm_wait", "pull", "hold", "observe"] * n
                          + ["release", "retreat", "done"])
    assert len(asked) == 1 + n and all(a.chosen is not None for a in asked)
    assert r["station"] == "hardware" and r["outcome"] is None    # no ground truth
    # The gripper closed until it stalled on the leaf (no simulator
    # acknowledgement): never below the leaf's opening (the commanded end of
    # the ramp is 0 mm).
    import re
    closed = [float(m) for m in re.findall(r"closed at ([0-9.]+) mm", " ".join(fake.log))]
    assert len(closed) == 1 and LEAF_OPENING * 1000 - 0.4 <= closed[0] < 20.0, closed
    # The commands followed the plan: at close_gripper the arm had been sent to
    # the chosen grasp (TCP within 5 mm of p_WG), and it was sent back to the
    # start pose at the end.
    X_WB = fake.scenario.robot.X_WB.GetDeterministicValue()
    p_WT = X_WB.multiply(TcpPositionInBase(fake.targets["close_gripper"]))
    assert np.linalg.norm(p_WT - np.array(r["chosen_action"]["p_WG"])) < 0.005
    assert np.allclose(fake.clients.ur.last_target, fake.scenario.robot.initial_q, atol=1e-6)
    # the gripper was opened again at release (POS register back toward open)
    assert fake.gripper.regs["PRE"] < OpeningToPos(LEAF_OPENING, fake.scenario.hardware.gripper)
    for f in ("episode.json", "plan.json", "candidates.json", "plan_on_image.png",
              "rgb.png", "depth.png", "rgb_after.png", "recording/recording.json"):
        assert (out / f).exists(), f
    # hardware runs are recorded with the device's intrinsics and the calibration
    sc = (out / "scenario.yaml").read_text()
    assert "no_return_free_range: 0.0" in sc
    assert f"link: {fake.link}" in sc and fake.gripper_writes >= 3   # activation, close, open
    if fake.link == "modbus_rtu":       # every request went over the RS-485 line
        assert all(fc in (3, 16) for fc, _, _ in fake.server.received)


def test_hardware_recording_replays_to_the_same_action(full_run, tmp_path):
    fake, out, *_ = full_run
    rec = LoadRecording(out)
    assert rec.station == "hardware"
    assert len(rec.views) == 2 + len(fake.record["motions"]) - 1     # one view per motion
    assert rec.views[0].label is None             # a real camera has no labels
    assert rec.camera["serial"] == "f0000001"
    files, record = ReplayRun(out, tmp_path / "replay", progress=print)
    assert record["same_action_as_run"] is True, (record["chosen_action"],
                                                  record["run_chosen_action"])
    assert (tmp_path / "replay" / "plan_on_image.png").exists()


def test_replay_with_other_settings_writes_its_own_plan(full_run, tmp_path):
    fake, out, *_ = full_run
    text = "{planner: {distances: [0.04], action_families: [pull]}}"
    _, record = ReplayRun(out, tmp_path / "r", text, progress=print)
    assert record["status"] == "ok" and record["chosen_action"]["distance"] == 0.04
    assert record["scenario_text"] == text


@pytest.mark.parametrize("state", ["capture", "plan_requested", "pregrasp", "approach",
                                   "close_gripper", "grasp_wait", "pull", "hold", "observe",
                                   "release", "retreat"])
def test_a_protective_stop_in_any_state_stops_the_arm_and_leaves_the_gripper(
        cell, tmp_path, state):
    fake = FakeCell(cell)
    fake.inject[state] = lambda: setattr(fake.clients.ur.receive, "protective_stopped", True)
    files, status = fake.run(tmp_path)
    assert status == "aborted"
    assert "protective stopped" in fake.record["message"]
    assert fake.modes[-1] == state          # stopped where it was; no further state
    assert fake.clients.ur._halted and fake.clients.ur.control.servo_stops
    # the gripper got no command after the stop (a held leaf is never dropped)
    assert fake.gripper.regs["PRE"] == fake.at_injection["PRE"]
    assert sum(r.startswith("SET") for r in fake.server.received) == fake.at_injection["sets"]
    assert (tmp_path / "episode.json").exists() and (tmp_path / "recording").is_dir()


def test_a_lost_gripper_link_while_holding_stops_the_arm(cell, tmp_path):
    fake = FakeCell(cell)
    fake.inject["pull"] = fake.server.DropClients
    _, status = fake.run(tmp_path)
    assert status == "aborted" and fake.clients.ur._halted
    assert fake.modes[-1] == "pull"


@pytest.mark.parametrize("failure", ["server_stops", "gripper_fault"])
def test_a_modbus_gripper_lost_or_faulted_while_holding_stops_the_arm(cell, tmp_path, failure):
    """``link: modbus_rtu``: the gripper's Modbus slave stops answering, or
    reports a fault (gFLT 0x0E, overcurrent), during the pull: the episode
    aborts with a clear message, the arm is stopped, and the gripper gets no
    further request (the leaf stays held)."""
    fake = FakeCell(cell, link="modbus_rtu")
    if failure == "server_stops":
        fake.inject["pull"] = fake.server.Stop
    else:
        fake.inject["pull"] = lambda: fake.gripper.regs.__setitem__("FLT", 0x0E)
    _, status = fake.run(tmp_path)
    assert status == "aborted" and fake.modes[-1] == "pull"
    assert fake.clients.ur._halted and fake.clients.ur.control.servo_stops
    expected = ("lost the link to the gripper on /dev/" if failure == "server_stops"
                else "reports fault 0x0E (overcurrent triggered)")
    assert expected in fake.record["message"], fake.record["message"]
    assert fake.gripper.regs["PRE"] == fake.at_injection["PRE"] > OpeningToPos(
        0.01, fake.scenario.hardware.gripper)
    assert fake.gripper_writes == fake.at_injection["sets"]


def test_ctrl_c_stops_the_arm_and_leaves_the_gripper_holding(cell, tmp_path):
    fake = FakeCell(cell)

    def interrupt():
        raise KeyboardInterrupt
    fake.inject["hold"] = interrupt
    with pytest.raises(KeyboardInterrupt):
        fake.run(tmp_path)
    assert fake.clients.ur._halted and fake.clients.ur.control.servo_stops
    # still commanded closed on the leaf (far past the 2 cm pre-grasp opening)
    assert fake.gripper.regs["PRE"] == fake.at_injection["PRE"] > OpeningToPos(
        0.01, fake.scenario.hardware.gripper)


def test_plan_only_captures_plans_and_moves_nothing(cell, tmp_path):
    fake = FakeCell(cell, read_only=True)
    sets_before = sum(r.startswith("SET") for r in fake.server.received)
    files, status = fake.run(tmp_path, plan_only=True)
    assert status == "planned"
    assert fake.modes == ["capture", "plan_requested", "planned"]
    assert fake.clients.ur.control is None and fake.clients.ur.servo_count == 0
    assert sum(r.startswith("SET") for r in fake.server.received) == sets_before
    plan = json.loads((tmp_path / "plan.json").read_text())
    assert plan["status"] == "ok" and plan["chosen_action"]["feasible"]
    for f in ("candidates.json", "plan_on_image.png", "recording/recording.json"):
        assert (tmp_path / f).exists(), f


@pytest.mark.parametrize("answer", ["no", "EOF"])
def test_confirm_refused_or_unanswered_moves_nothing(cell, tmp_path, monkeypatch, answer):
    import builtins

    def fake_input(prompt=""):
        if answer == "EOF":
            raise EOFError
        return answer
    monkeypatch.setattr(builtins, "input", fake_input)
    fake = FakeCell(cell)
    _, status = fake.run(tmp_path, confirm=True, confirm_fn=ConsoleConfirm)
    assert status == "aborted"
    assert fake.modes[-2:] == ["confirm_wait", "aborted"]
    assert "not confirmed by the operator" in fake.record["message"]
    assert ("end of input" in fake.record["message"]) == (answer == "EOF")
    q0 = np.asarray(fake.scenario.robot.initial_q)
    assert len(fake.servoed) and np.abs(fake.servoed - q0).max() < 1e-9   # held still


def test_a_plan_leaving_the_workspace_is_refused_before_anything_moves(cell, tmp_path):
    """The workspace box holds the start pose but not the chosen grasp: the
    controller checks the whole pre-grasp -> approach -> pull motion at
    planning time and aborts; the arm was only ever held where it was."""
    import copy
    fake = FakeCell(cell)
    fake.scenario = copy.deepcopy(fake.scenario)
    fake.scenario.hardware.ur.workspace_min = [-0.35, -0.85, -0.2]   # grasp at x = -0.42
    _, status = fake.run(tmp_path)
    assert status == "aborted"
    assert fake.modes[-2:] == ["plan_requested", "aborted"]
    assert "refused by the safety checks in plan_requested" in fake.record["message"]
    assert "outside the workspace box on x" in fake.record["message"]
    q0 = np.asarray(fake.scenario.robot.initial_q)
    assert np.abs(fake.servoed - q0).max() < 1e-9


def test_a_grasp_that_meets_no_leaf_is_not_pulled(cell, tmp_path):
    """The pads close to the end of the ramp without the gripper reporting an
    object (the leaf slipped away, or is thinner than the ramp's end): the
    controller does not pull an empty gripper; it opens, backs out along the
    approach and the episode aborts saying so."""
    fake = FakeCell(cell, leaf_opening=None)
    _, status = fake.run(tmp_path)
    assert status == "aborted"
    assert fake.modes[-4:] == ["approach", "close_gripper", "retreat", "aborted"], fake.modes
    assert "pull" not in fake.modes
    assert fake.record["message"].startswith("grasp missed: the gripper closed to 0.0 mm")
    w1 = OpeningToPos(fake.scenario.planner.grasp_close_width, fake.scenario.hardware.gripper)
    assert fake.gripper.regs["PRE"] < w1 - 50               # opened again
    assert np.allclose(fake.clients.ur.last_target, fake.scenario.robot.initial_q, atol=1e-6)
