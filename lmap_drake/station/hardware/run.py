"""Getting the real cell ready for an episode (``lmap-drake run --hardware``).

``PrepareHardware`` does, before anything can move:

1. checks the client libraries (when it connects itself), the ``hardware``
   config and the calibration file (present, well-formed, a fixed finite
   ``X_WC``);
2. connects the UR5, the gripper and the camera (``read_only`` for
   ``--plan-only`` / ``--dry-run``: RTDE receive only, no control script, no
   gripper activation, so nothing can move);
3. refuses a calibration made for another camera serial;
4. returns the scenario as the hardware sees it: camera0 with the device's
   intrinsics and the calibrated pose, ``perception.no_return_free_range``
   0 (a real camera's missing returns say nothing about free space), and
   refuses the ``label`` segmenter (a real camera has no labels).

The episode itself is ``lmap_drake.episode.RunLmapEpisode(hardware=True)``.
"""
from __future__ import annotations

import copy
from typing import Callable

from lmap_drake.errors import HardwareStationUnavailable
from lmap_drake.scenario import Scenario, ScenarioWithCamera
from lmap_drake.station.hardware.station import (CheckHardwareSetup, ConnectHardwareClients,
                                                 HardwareClients)
from lmap_drake.station.hardware_config import CalibrationError, CheckCalibrationSerial


def _Unavailable(msg: str) -> Exception:
    return HardwareStationUnavailable(msg)


def HardwareScenario(scenario: Scenario, clients: HardwareClients, X_WC) -> Scenario:
    """``scenario`` as run on the cell (see the module docstring, step 4)."""
    info = clients.camera.CameraInfo()
    camera = {"width": info.width(), "height": info.height(), "fx": info.focal_x(),
              "fy": info.focal_y(), "cx": info.center_x(), "cy": info.center_y()}
    s = ScenarioWithCamera(scenario, camera, X_WC)
    s.perception = copy.deepcopy(s.perception)
    s.perception.no_return_free_range = 0.0
    return s


def PrepareHardware(scenario: Scenario, clients: HardwareClients | None = None,
                    read_only: bool = False, progress: Callable[[str], None] = print
                    ) -> tuple[Scenario, HardwareClients, bool]:
    """Checks, connects (unless ``clients`` are given, e.g. the project's
    fakes) and returns (hardware scenario, clients, whether we connected
    them). Raises HardwareStationUnavailable (exit code 1) or
    CalibrationError (bad input, exit code 2) before anything moves."""
    config = scenario.hardware
    if scenario.perception.segmenter == "label":
        raise _Unavailable("hardware station: perception.segmenter 'label' reads simulator "
                           "labels, which a real camera does not have; use segnet (the "
                           "default) or color_depth")
    own = clients is None
    calib, X_WC = CheckHardwareSetup(scenario, own)
    if own:
        progress(f"connecting to the UR5 at {config.ur.robot_ip}"
                 + (" (read-only: nothing can move)" if read_only else ""))
        clients = ConnectHardwareClients(config, read_only=read_only)
    try:
        serial = str(getattr(clients.camera, "serial", ""))
        CheckCalibrationSerial(calib, serial, config.camera.calibration_file)
        q, _ = clients.ur.ReadState()
        progress(f"UR5 at q = {[round(float(x), 4) for x in q]} rad; gripper opening "
                 f"{clients.gripper.Opening() * 1000:.1f} mm; camera {serial or '(no serial)'}")
        return HardwareScenario(scenario, clients, X_WC), clients, own
    except BaseException:
        if own:
            clients.Close()
        raise
