"""``lmap-drake replay BAG``: a simulated capture of the default scenario
(the station's camera0 view with its L515 camera model, as a run records
it) written as a ROS 2 bag and as a RealSense-style ROS 1 bag with the real
``rosbags`` writers, replayed through the command line with the example
calibration file (the simulated camera's pose), chooses the action the
replay of the original recording chooses; bad bags and bad options end in
one line, exit code 2, nothing written."""
from __future__ import annotations

import json

import numpy as np
import pytest

from lmap_drake.cli import main
from lmap_drake.episode import ReplayRun
from lmap_drake.episode.records import RecordingCamera
from lmap_drake.paths import DEFAULT_SCENARIO_FILE, REPO_ROOT
from lmap_drake.perception.recording import CapturedView, LoadRecording, SaveRecording
from lmap_drake.plants.plant_station import MakePlantStation
from lmap_drake.scenario import DumpScenario, LoadScenario
from perception.bag_files import WriteRealSenseBag, WriteRos2Bag

CALIBRATION = str(REPO_ROOT / "diagrams" / "calibration_example.yaml")
ACTION_KEYS = ("grasp_id", "direction_id", "distance", "family", "angle_deg")


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """A run folder holding the default scenario's simulated capture (view
    0 with the arm at ``robot.initial_q``), its replay, and the two bags."""
    root = tmp_path_factory.mktemp("bags")
    s = LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name="Defaults")
    station = MakePlantStation(s)
    ctx = station.CreateDefaultContext()
    rgb = np.array(station.GetOutputPort("camera0.rgb_image").Eval(ctx).data)
    depth = np.array(station.GetOutputPort("camera0.depth_image").Eval(ctx).data[..., 0])
    label = np.array(station.GetOutputPort("camera0.label_image").Eval(ctx).data[..., 0])
    camera, X_WC = RecordingCamera(s)
    q = np.asarray(s.robot.initial_q, float)
    run = root / "run"
    SaveRecording(run, [CapturedView(0, 0.0, 0.0, rgb, depth, label, q, np.zeros(6),
                                     np.full(3, np.nan))], camera, X_WC, "simulation")
    DumpScenario(s, run / "scenario.yaml")
    _, replay = ReplayRun(run, root / "replay", progress=print)
    frames = [{"rgb": rgb, "depth": depth}] * 3        # a short clip: frame 1 is picked
    return {"root": root, "rgb": rgb, "depth": depth, "X_WC": X_WC, "q": q, "replay": replay,
            "ros2": WriteRos2Bag(root / "ros2_bag", frames, camera, q=q),
            "realsense": WriteRealSenseBag(root / "capture.bag", frames, camera)}


def _ReplayBag(capture, kind, *extra):
    out = capture["root"] / f"replay_{kind}"
    assert main(["replay", str(capture[kind]), "--calibration", CALIBRATION, "--output",
                 str(out), *extra]) == 0
    return out, json.loads((out / "replay.json").read_text())


@pytest.fixture(scope="module")
def bag_replays(capture):
    return {"ros2": _ReplayBag(capture, "ros2", "--time", "0.04"),
            "realsense": _ReplayBag(capture, "realsense", "--index", "1")}


def test_a_bag_replays_to_the_action_of_the_recorded_capture(capture, bag_replays):
    """The issue's target: the ROS 2 bag and the RealSense-style bag each
    choose the action the original recording's replay chose; the two bags
    (converted to the very same view) give identical plans, candidates and
    all."""
    original = capture["replay"]["chosen_action"]
    assert original is not None and capture["replay"]["status"] == "ok"
    plans = {}
    for kind, (out, record) in bag_replays.items():
        assert record["status"] == "ok", record["message"]
        assert {k: record["chosen_action"][k] for k in ACTION_KEYS} == \
            {k: original[k] for k in ACTION_KEYS}, kind
        assert record["same_action_as_run"] is None          # a bag has no run to compare
        assert record["bag"]["frame_index"] == 1 and record["run"] == str(capture[kind])
        candidates = json.loads((out / "candidates.json").read_text())
        candidates.pop("timings")
        plans[kind] = (record["chosen_action"], candidates)
    assert plans["ros2"] == plans["realsense"]


def test_the_converted_recording_is_the_capture(capture, bag_replays):
    """The output folder holds the view as the project's recording (a
    hardware capture: no labels), exactly: the images, the camera pose from
    the calibration file, the joints from the ROS 2 bag's joint states or
    the scenario's initial_q; it replays again like any run folder."""
    for kind, (out, _) in bag_replays.items():
        rec = LoadRecording(out)
        view = rec.views[0]
        assert rec.station == "hardware" and view.label is None and len(rec.views) == 1
        assert np.array_equal(view.rgb, capture["rgb"])
        assert np.array_equal(view.depth, capture["depth"])
        assert np.allclose(rec.X_WC, capture["X_WC"], rtol=0, atol=1e-12)
        assert np.allclose(view.q, capture["q"])
        source = json.loads((out / "bag.json").read_text())
        assert source["kind"] == kind
        assert source["joints"] == ("bag" if kind == "ros2" else "scenario robot.initial_q")
        # a hardware capture: its no-return pixels carved nothing
        assert "no_return_free_range: 0.0" in (out / "scenario.yaml").read_text()
        for name in ("scenario.yaml", "plan.json", "candidates.json", "plan_on_image.png",
                     "rgb_before_segmented.png", "recording/recording.json"):
            assert (out / name).stat().st_size > 0, name
    assert LoadRecording(bag_replays["realsense"][0]).camera["serial"] == "f0000001"


@pytest.mark.parametrize("argv, message", [
    (["--calibration", "nothing.yaml"], "camera calibration file not found"),
    ([], "needs --calibration FILE"),
    (["--calibration", CALIBRATION, "--topics", "colour=/x"], "unknown role 'colour'"),
    (["--calibration", CALIBRATION, "--index", "7"], "--index 7: colour topic"),
    (["--calibration", CALIBRATION, "--topics", "depth=/camera/depth/none"],
     "no topic /camera/depth/none (depth)"),
])
def test_bad_bag_replays_end_in_one_line_and_write_nothing(capture, capsys, argv, message):
    out = capture["root"] / "never"
    assert main(["replay", str(capture["ros2"]), "--output", str(out), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1 and "Traceback" not in err
    assert not out.exists()


def test_an_unreadable_bag_and_bag_options_on_a_run_folder(capture, tmp_path, capsys):
    junk = tmp_path / "broken.bag"
    junk.write_bytes(b"\x00" * 100)
    assert main(["replay", str(junk), "--calibration", CALIBRATION, "--output",
                 str(tmp_path / "o")]) == 2
    assert f"bag {junk} is not a readable ROS 1 / ROS 2 bag" in capsys.readouterr().err
    assert main(["replay", str(capture["root"] / "run"), "--index", "0", "--output",
                 str(tmp_path / "o")]) == 2
    assert "--time, --index, --topics and --calibration are for replaying a bag" in \
        capsys.readouterr().err
    assert not (tmp_path / "o").exists()
