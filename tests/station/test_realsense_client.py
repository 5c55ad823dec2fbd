"""RealSenseClient with a FAKE pyrealsense2 module (FakePyrealsense2 from
tests/fakes/hardware.py: the module names the client uses, a
synthetic scene, no camera)."""
import sys

import numpy as np
import pytest

from fakes.hardware import FakePyrealsense2
from lmap_drake.station.hardware.realsense_client import ConnectRealSense
from lmap_drake.station.hardware_config import RealSenseConfig
from lmap_drake.errors import HardwareStationUnavailable


def test_missing_pyrealsense2_gives_install_hint(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyrealsense2", None)
    with pytest.raises(HardwareStationUnavailable, match=r"2\.54\.2\.5684.*pip install -e \.\[hardware\]"):
        ConnectRealSense(RealSenseConfig())


def test_streams_configured_as_asked():
    rs = FakePyrealsense2(serial="f111")
    cam = ConnectRealSense(RealSenseConfig(serial="f111", fps=15, depth_width=1024,
                                           depth_height=768), rs=rs)
    cfg = rs.last_config
    assert cfg.device == "f111"
    assert cfg.streams[rs.stream.color] == (640, 480, rs.format.rgb8, 15)
    assert cfg.streams[rs.stream.depth] == (1024, 768, rs.format.z16, 15)
    assert cam.serial == "f111"
    cam.Close()
    cam.Close()
    assert rs.stopped == 1


def test_depth_aligned_to_colour_in_metres_with_device_scale():
    rs = FakePyrealsense2(depth_scale=0.00025, plane_depth=0.8, disc_depth=0.6)
    # Depth streams at 1024x768: only alignment to colour gives 640x480.
    cam = ConnectRealSense(RealSenseConfig(depth_width=1024, depth_height=768), rs=rs)
    assert cam.depth_scale == 0.00025
    rgba, depth = cam.Capture()
    assert rgba.shape == (480, 640, 4) and rgba.dtype == np.uint8
    assert (rgba[..., 3] == 255).all()
    assert depth.shape == (480, 640) and depth.dtype == np.float32
    assert depth[240, 320] == pytest.approx(0.6, abs=1e-6)  # disc
    assert depth[50, 600] == pytest.approx(0.8, abs=1e-6)  # plane
    assert tuple(rgba[240, 320, :3]) == (200, 20, 20)
    # Raw 0 (no return) -> +inf (Drake's kTooFar), never 0.
    assert np.isinf(depth[:, :60]).all() and (depth > 0).all()


def test_intrinsics_become_a_drake_camera_info():
    cam = ConnectRealSense(RealSenseConfig(), rs=FakePyrealsense2())
    info = cam.CameraInfo()
    i = cam.intrinsics
    assert (info.width(), info.height()) == (640, 480)
    assert info.focal_x() == pytest.approx(i.fx) and info.focal_y() == pytest.approx(i.fy)
    assert info.center_x() == pytest.approx(i.ppx) and info.center_y() == pytest.approx(i.ppy)


def test_wrong_serial_gives_clear_error():
    with pytest.raises(HardwareStationUnavailable, match="could not start the RealSense camera "
                                                        r"\(serial f999"):
        ConnectRealSense(RealSenseConfig(serial="f999"), rs=FakePyrealsense2(serial="f111"))
