"""Thin client for the RealSense L515 through pyrealsense2.

``ConnectRealSense`` imports ``pyrealsense2`` lazily (the last release with
L515 support is 2.54.x; the ``[hardware]`` extra pins 2.54.2.5684) and starts
a pipeline with a colour stream (rgb8) and a depth stream (z16). Each
``Capture`` waits for a frameset, aligns depth to colour (``rs.align``), and
returns:

- colour as HxWx4 uint8 RGBA (alpha 255), the layout of Drake's ImageRgba8U;
- depth as HxW float32 metres: raw z16 times the depth scale read from the
  device's depth sensor. Raw 0 means "no return" on a RealSense (too far, too
  close, or no signal; they cannot be told apart); it becomes +inf, Drake's
  ``kTooFar`` value, so that every consumer that drops non-finite depth
  drops it, and no zero-depth point lands at the camera centre.

``CameraInfo`` is the colour stream's intrinsics (pinhole; the L515 colour
distortion is ignored) as a Drake ``CameraInfo``.
"""
from __future__ import annotations

import numpy as np
from pydrake.systems.sensors import CameraInfo

from lmap_drake.errors import HardwareStationUnavailable
from lmap_drake.station.hardware.safety import HardwareAbort
from lmap_drake.station.hardware_config import RealSenseConfig

INSTALL_HINT = "pip install -e .[hardware]"


def ImportPyrealsense2():
    """The pyrealsense2 module, or HardwareStationUnavailable."""
    try:
        import pyrealsense2 as rs
    except ImportError as err:
        raise HardwareStationUnavailable(
            f"the hardware station needs pyrealsense2==2.54.2.5684 (the last release that "
            f"supports the L515), which is not installed ({err}); install the hardware "
            f"extra: {INSTALL_HINT}") from err
    return rs


def ConnectRealSense(config: RealSenseConfig, rs=None) -> "RealSenseClient":
    """Starts the camera. ``rs`` is the pyrealsense2 module (injectable)."""
    rs = rs if rs is not None else ImportPyrealsense2()
    pipeline = rs.pipeline()
    cfg = rs.config()
    if config.serial:
        cfg.enable_device(config.serial)
    cfg.enable_stream(rs.stream.depth, config.depth_width, config.depth_height,
                      rs.format.z16, config.fps)
    cfg.enable_stream(rs.stream.color, config.width, config.height, rs.format.rgb8, config.fps)
    try:
        profile = pipeline.start(cfg)
    except Exception as err:  # pyrealsense2 raises RuntimeError
        which = f"serial {config.serial}" if config.serial else "any serial"
        raise HardwareStationUnavailable(
            f"hardware station: could not start the RealSense camera ({which}, colour "
            f"{config.width}x{config.height}, depth {config.depth_width}x"
            f"{config.depth_height} @ {config.fps} fps): {err}") from err
    return RealSenseClient(config, rs, pipeline, profile)


class RealSenseClient:
    """A started pyrealsense2 pipeline with depth aligned to colour."""

    def __init__(self, config: RealSenseConfig, rs, pipeline, profile):
        self.config = config
        self._rs = rs
        self._pipeline = pipeline
        device = profile.get_device()
        self.serial = str(device.get_info(rs.camera_info.serial_number))
        self.depth_scale = float(device.first_depth_sensor().get_depth_scale())
        intr = profile.get_stream(rs.stream.color).as_video_stream_profile().get_intrinsics()
        self.intrinsics = intr
        self._align = rs.align(rs.stream.color)
        self._closed = False
        if (intr.width, intr.height) != (config.width, config.height):
            raise HardwareAbort(
                f"RealSense colour stream is {intr.width}x{intr.height}, configured "
                f"{config.width}x{config.height}")

    def CameraInfo(self) -> CameraInfo:
        i = self.intrinsics
        return CameraInfo(int(i.width), int(i.height), float(i.fx), float(i.fy),
                          float(i.ppx), float(i.ppy))

    def Capture(self) -> tuple[np.ndarray, np.ndarray]:
        """(rgba HxWx4 uint8, depth HxW float32 metres, +inf = no return)."""
        timeout_ms = int(self.config.frame_timeout * 1000)
        try:
            frames = self._pipeline.wait_for_frames(timeout_ms)
        except Exception as err:
            raise HardwareAbort(f"hardware episode aborted: no RealSense frames within "
                                f"{self.config.frame_timeout} s ({err})") from err
        aligned = self._align.process(frames)
        color = aligned.get_color_frame()
        depth = aligned.get_depth_frame()
        if not color or not depth:
            raise HardwareAbort("RealSense frameset lacks a colour or an aligned depth frame")
        rgb = np.asanyarray(color.get_data())
        raw = np.asanyarray(depth.get_data())
        h, w = self.config.height, self.config.width
        if rgb.shape != (h, w, 3) or raw.shape != (h, w):
            raise HardwareAbort(f"RealSense frames have shapes {rgb.shape} and {raw.shape}; "
                                f"expected ({h}, {w}, 3) and ({h}, {w})")
        rgba = np.empty((h, w, 4), np.uint8)
        rgba[..., :3] = rgb
        rgba[..., 3] = 255
        metres = raw.astype(np.float32) * np.float32(self.depth_scale)
        metres[raw == 0] = np.inf
        return rgba, metres

    def Close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self._pipeline.stop()
        except Exception:
            pass
