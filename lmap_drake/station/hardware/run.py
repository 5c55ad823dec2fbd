"""Getting the real cell ready for an episode (``lmap-drake run --hardware``).

``PrepareHardware`` goes through the pre-motion gate
(``station.hardware.station.OpenCheckedHardware``): every check runs before
the first byte that can move anything:

1. the scenario (``CheckHardwareScenario``): not the ``label`` segmenter (a
   real camera has no labels), the client libraries (when it connects
   itself), the ``hardware`` config and the calibration file (present,
   well-formed, a fixed rigid ``X_WC``);
2. connects read-only (RTDE receive, the gripper's socket, the camera),
   refuses a calibration made for another camera serial and a start pose
   the safety checks would refuse (joint limits, workspace box);
3. only then uploads ur_rtde's control script and activates the gripper
   (never with ``read_only``: ``--plan-only`` / ``--dry-run``);
4. returns the scenario as the hardware sees it: camera0 with the device's
   intrinsics and the calibrated pose, ``perception.no_return_free_range``
   0 (a real camera's missing returns say nothing about free space).

The episode itself is ``lmap_drake.episode.RunLmapEpisode(hardware=True)``.
"""
from __future__ import annotations

import copy
from typing import Callable

from lmap_drake.scenario import Scenario, ScenarioWithCamera
from lmap_drake.station.hardware.station import HardwareClients, OpenCheckedHardware


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
    """The pre-motion gate (see the module docstring), connecting unless
    ``clients`` are given (e.g. the project's fakes); returns (hardware
    scenario, clients, whether we connected them). Raises
    HardwareStationUnavailable (exit code 1), or ConfigError /
    CalibrationError (bad input, exit code 2) before anything can move."""
    clients, X_WC, own = OpenCheckedHardware(scenario, clients, read_only, progress)
    try:
        q, _ = clients.ur.ReadState()
        serial = str(getattr(clients.camera, "serial", ""))
        progress(f"UR5 at q = {[round(float(x), 4) for x in q]} rad; gripper opening "
                 f"{clients.gripper.Opening() * 1000:.1f} mm; camera {serial or '(no serial)'}")
        return HardwareScenario(scenario, clients, X_WC), clients, own
    except BaseException:
        if own:
            clients.Close()
        raise
