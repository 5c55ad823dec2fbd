"""``lmap-drake replay BAG``: one view of a RealSense / ROS 1 / ROS 2 bag
(``perception.bags``) converted into a run folder (``recording/`` holding
that view as view 0, ``scenario.yaml``, ``bag.json``), then replayed by
``ReplayRun`` like any run.

The camera pose ``X_WC`` comes from a calibration file
(``station.hardware_config.CameraCalibration``, the hardware station's
format). A bag without joints gets the scenario's ``robot.initial_q`` as
the arm's joints (the IK seed and the robot self-filter's pose); the view
is recorded as a ``hardware`` capture (no labels, ``no_return_free_range``
0 in the replay unless ``scenario_text`` sets it).
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Callable

import numpy as np

from lmap_drake.episode.replay import ReplayRun
from lmap_drake.perception.bags import BagCapture, ReadBagCapture
from lmap_drake.perception.recording import CapturedView, SaveRecording
from lmap_drake.scenario import DumpScenario, Scenario
from lmap_drake.station.hardware_config import (CalibrationX_WC, CheckCalibrationSerial,
                                                LoadCameraCalibration)

BAG_SOURCE_FILE = "bag.json"


def LoadBagView(bag, calibration_file: str, scenario: Scenario, time: float | None = None,
                index: int | None = None, topics: dict | None = None
                ) -> tuple[BagCapture, np.ndarray]:
    """(the capture, X_WC 4x4) of the bag's view at ``time`` / ``index``;
    raises BagError / CalibrationError (one line, naming the file or topic)
    before anything is written."""
    calib = LoadCameraCalibration(str(calibration_file))
    capture = ReadBagCapture(bag, time=time, index=index, topics=topics)
    CheckCalibrationSerial(calib, capture.camera.get("serial", ""), str(calibration_file))
    X_WB = scenario.robot.X_WB.GetDeterministicValue()
    return capture, CalibrationX_WC(calib, X_WB).GetAsMatrix4()


def WriteBagRun(capture: BagCapture, X_WC: np.ndarray, scenario: Scenario, run: Path,
                calibration_file: str = "") -> list[str]:
    """Writes ``run/recording/`` (the capture as view 0, station
    ``hardware``), ``run/scenario.yaml`` and ``run/bag.json`` (what was read
    from which bag); returns the written paths relative to ``run``."""
    run = Path(run)
    q = capture.q if capture.q is not None else np.asarray(scenario.robot.initial_q, float)
    view = CapturedView(0, capture.t, capture.wall_time, capture.rgb, capture.depth, None,
                        np.asarray(q, float), np.zeros(6), np.full(3, np.nan))
    files = SaveRecording(run, [view], capture.camera, X_WC, "hardware")
    DumpScenario(scenario, run / "scenario.yaml")
    source = dict(capture.source, calibration_file=str(calibration_file),
                  joints="bag" if capture.q is not None else "scenario robot.initial_q")
    (run / BAG_SOURCE_FILE).write_text(json.dumps(source, indent=1, default=str))
    return files + ["scenario.yaml", BAG_SOURCE_FILE]


def ReplayBag(capture: BagCapture, X_WC: np.ndarray, scenario: Scenario, out: Path,
              scenario_text: str = "{}", calibration_file: str = "",
              progress: Callable[[str], None] = print) -> tuple[list[str], dict]:
    """The bag's view converted into ``out`` (``WriteBagRun``), then
    ``ReplayRun`` on it, writing its outputs into ``out`` too."""
    out = Path(out)
    src = capture.source
    progress(f"bag {src['bag']} ({src['kind']}): colour frame {src['frame_index']} of "
             f"{src['frames']} at {src['t']:.3f} s, depth {src['alignment']}")
    files = WriteBagRun(capture, X_WC, scenario, out, calibration_file)
    replayed, record = ReplayRun(out, out, scenario_text, progress=progress)
    record["run"], record["bag"] = src["bag"], src
    (out / "replay.json").write_text(json.dumps(record, indent=1, default=float))
    return sorted(set(files) | set(replayed)), record
