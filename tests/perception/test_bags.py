"""``perception.bags`` on bags written here with the real ``rosbags``
writers (tests/perception/bag_files.py): one RGB-D view read back exactly
from a ROS 2 bag and a RealSense-style ROS 1 bag, frames picked by time and
index, encodings, depth alignment, and bad bags named in one line."""
from __future__ import annotations

import numpy as np
import pytest

from lmap_drake.perception.bags import (AlignDepthToColor, BagError, ParseTopics,
                                        ReadBagCapture)
from perception.bag_files import WriteRealSenseBag, WriteRos2Bag

CAMERA = {"width": 64, "height": 48, "fx": 60.0, "fy": 61.0, "cx": 31.5, "cy": 23.5}


def _Frames(n=3, seed=0):
    """``n`` views with distinct content; depth on a 0.25 mm grid, a few
    no-return pixels."""
    rng = np.random.default_rng(seed)
    frames = []
    for k in range(n):
        rgb = rng.integers(0, 256, (48, 64, 4), dtype=np.uint8)
        rgb[..., 3] = 255
        depth = (np.rint(rng.uniform(0.3, 1.5, (48, 64)) / 0.00025) * 0.00025).astype(np.float32)
        depth[k:k + 3, 5:9] = np.inf
        frames.append({"rgb": rgb, "depth": depth})
    return frames


@pytest.fixture(scope="module")
def frames():
    return _Frames()


@pytest.fixture(scope="module")
def ros2_bag(tmp_path_factory, frames):
    return WriteRos2Bag(tmp_path_factory.mktemp("b") / "ros2", frames, CAMERA,
                        q=[0.1, -1.2, 1.3, -1.6, -1.5, 0.2])


@pytest.fixture(scope="module")
def realsense_bag(tmp_path_factory, frames):
    return WriteRealSenseBag(tmp_path_factory.mktemp("b") / "capture.bag", frames, CAMERA)


def test_a_ros2_bag_gives_the_recorded_view_exactly(ros2_bag, frames):
    c = ReadBagCapture(ros2_bag, index=1)
    assert np.array_equal(c.rgb, frames[1]["rgb"])
    assert np.array_equal(c.depth, frames[1]["depth"]) and c.depth.dtype == np.float32
    assert {k: c.camera[k] for k in CAMERA} == CAMERA and np.isnan(c.camera["depth_scale"])
    assert np.allclose(c.q, [0.1, -1.2, 1.3, -1.6, -1.5, 0.2])
    assert c.source["kind"] == "ros2" and c.source["frames"] == 3
    assert c.source["topics"]["depth"] == "/camera/aligned_depth_to_color/image_raw"
    assert c.source["alignment"] == "aligned (as recorded)"
    # by time: the colour frame nearest 0.07 s is frame 2 (0.066 s)
    assert ReadBagCapture(ros2_bag, time=0.07).source["frame_index"] == 2
    assert ReadBagCapture(ros2_bag, time=0.01).source["frame_index"] == 0
    assert ReadBagCapture(ros2_bag).source["frame_index"] == 0


def test_a_realsense_bag_gives_the_recorded_view_exactly(realsense_bag, frames):
    """Z16 depth in the file's depth unit (0.25 mm, an L515), both streams'
    extrinsics identity: the depth on its 0.25 mm grid comes back bit for
    bit; the serial and the depth unit are read from the file."""
    c = ReadBagCapture(realsense_bag, index=2)
    assert np.array_equal(c.rgb, frames[2]["rgb"])
    assert np.array_equal(c.depth, frames[2]["depth"])
    assert c.camera["serial"] == "f0000001" and c.camera["depth_scale"] == 0.00025
    assert c.q is None and c.source["kind"] == "realsense"
    assert c.source["topics"]["color"] == "/device_0/sensor_1/Color_0/image/data"
    assert "identity extrinsics" in c.source["alignment"]


@pytest.mark.parametrize("encoding", ["bgr8", "rgba8", "bgra8", "png"])
def test_colour_encodings(tmp_path, frames, encoding):
    """Raw encodings and a PNG CompressedImage (found by its type)."""
    bag = WriteRos2Bag(tmp_path / "b", frames[:1], CAMERA, color_encoding=encoding)
    assert np.array_equal(ReadBagCapture(bag).rgb, frames[0]["rgb"])


def test_16bit_ros_depth_is_millimetres(tmp_path, frames):
    bag = WriteRos2Bag(tmp_path / "b", frames[:1], CAMERA, depth_encoding="16UC1")
    c = ReadBagCapture(bag)
    d = frames[0]["depth"]
    assert np.array_equal(np.isinf(c.depth), np.isinf(d))
    fin = np.isfinite(d)
    assert np.abs(c.depth[fin] - d[fin]).max() <= 0.0005 + 1e-6


def _PlaneSeenFrom(K: dict, X_CD: np.ndarray, z_plane: float) -> np.ndarray:
    """Depth camera D's image of the plane z_C = z_plane (ray cast)."""
    v, u = np.mgrid[0:K["height"], 0:K["width"]]
    r = np.stack([(u - K["cx"]) / K["fx"], (v - K["cy"]) / K["fy"], np.ones_like(u, float)])
    r_C = np.einsum("ij,jhw->ihw", X_CD[:3, :3], r)
    s = (z_plane - X_CD[2, 3]) / r_C[2]
    return s.astype(np.float32)        # depth along D's axis = s (r_z = 1)


def test_alignment_reprojects_a_lower_resolution_depth_camera_into_colour():
    """A 32x24 depth camera, 2 cm beside the colour camera and turned 3
    degrees, sees the plane z_C = 0.8 m: aligned into the 64x48 colour
    camera, every colour pixel its footprints cover reads 0.8 m, and they
    cover the colour image except a border strip."""
    from scipy.spatial.transform import Rotation
    K_D = {"width": 32, "height": 24, "fx": 30.0, "fy": 30.5, "cx": 15.5, "cy": 11.5}
    X_CD = np.eye(4)
    X_CD[:3, :3] = Rotation.from_euler("y", 3, degrees=True).as_matrix()
    X_CD[:3, 3] = [0.02, 0.0, 0.0]
    depth = _PlaneSeenFrom(K_D, X_CD, 0.8)
    aligned = AlignDepthToColor(depth, K_D, CAMERA, X_CD)
    assert aligned.shape == (48, 64) and aligned.dtype == np.float32
    seen = np.isfinite(aligned)
    assert np.allclose(aligned[seen], 0.8, atol=1e-5)
    assert seen[4:-4, 8:-8].all() and seen.mean() > 0.8
    # identity extrinsics and the same camera: every pixel maps onto itself
    same = AlignDepthToColor(np.full((48, 64), 0.5, np.float32), CAMERA, CAMERA, np.eye(4))
    assert np.array_equal(same, np.full((48, 64), 0.5, np.float32))


def test_a_realsense_bag_with_a_separate_depth_camera_is_aligned(tmp_path):
    from scipy.spatial.transform import Rotation
    K_D = {"width": 32, "height": 24, "fx": 30.0, "fy": 30.5, "cx": 15.5, "cy": 11.5}
    X_CD = np.eye(4)
    X_CD[:3, :3] = Rotation.from_euler("x", -2, degrees=True).as_matrix()
    X_CD[:3, 3] = [-0.015, 0.001, 0.0]
    rgb = np.full((48, 64, 4), 200, np.uint8)
    frame = {"rgb": rgb, "depth": _PlaneSeenFrom(K_D, X_CD, 0.7)}
    bag = WriteRealSenseBag(tmp_path / "c.bag", [frame], CAMERA, depth_camera=K_D, X_CD=X_CD)
    c = ReadBagCapture(bag)
    assert c.source["alignment"] == "re-projected into the colour camera"
    seen = np.isfinite(c.depth)
    assert seen.mean() > 0.8 and np.allclose(c.depth[seen], 0.7, atol=0.0003)


def test_topics_are_parsed_and_checked():
    assert ParseTopics("color=/a, depth=/b,info=/c") == {"color": "/a", "depth": "/b",
                                                         "info": "/c"}
    with pytest.raises(BagError, match="unknown role 'colour'"):
        ParseTopics("colour=/a")
    with pytest.raises(BagError, match="is not ROLE=TOPIC"):
        ParseTopics("color")


def _Error(path, **kw) -> str:
    with pytest.raises(BagError) as err:
        ReadBagCapture(path, **kw)
    msg = str(err.value)
    assert "\n" not in msg
    return msg


def test_bad_bags_are_named_in_one_line(tmp_path, frames, ros2_bag, realsense_bag):
    one = frames[:1]
    # unreadable
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"not a bag at all")
    assert f"bag {junk} is not a readable ROS 1 / ROS 2 bag" in _Error(junk)
    assert "not found" in _Error(tmp_path / "nothing.bag")
    # missing topics
    msg = _Error(WriteRos2Bag(tmp_path / "nocolor", one, CAMERA, skip=("color",)))
    assert "no color topic found" in msg and "--topics color=TOPIC" in msg
    msg = _Error(WriteRos2Bag(tmp_path / "noinfo", one, CAMERA, skip=("info",)))
    assert "no info topic found" in msg
    msg = _Error(ros2_bag, topics={"depth": "/camera/depth/nothing"})
    assert "no topic /camera/depth/nothing (depth)" in msg
    msg = _Error(ros2_bag, topics={"info": "/camera/color/image_raw"})
    assert "topic /camera/color/image_raw (camera info) is sensor_msgs/msg/Image" in msg
    # mismatched sizes: the camera info says 80x48, the images are 64x48
    wide = dict(CAMERA, width=80)
    msg = _Error(WriteRos2Bag(tmp_path / "wide", one, wide))
    assert "colour topic /camera/color/image_raw is 64x48" in msg and "80x48" in msg
    # unknown encodings
    msg = _Error(WriteRos2Bag(tmp_path / "yuv", one, CAMERA, color_encoding="yuv422"))
    assert "colour topic /camera/color/image_raw: unknown encoding 'yuv422'" in msg
    msg = _Error(WriteRealSenseBag(tmp_path / "d.bag", one, CAMERA, depth_encoding="32SC1"))
    assert "depth topic /device_0/sensor_0/Depth_0/image/data: unknown encoding" in msg
    # RealSense without the depth unit; out-of-range frame choices
    msg = _Error(WriteRealSenseBag(tmp_path / "u.bag", one, CAMERA, skip=("units",)))
    assert "no depth unit topic /device_0/sensor_0/option/Depth Units/value" in msg
    assert "--index 3" in _Error(realsense_bag, index=3)
    assert "--time 5.0" in _Error(ros2_bag, time=5.0)
    # a depth camera that is not aligned and no extrinsics
    K_D = {"width": 32, "height": 24, "fx": 30.0, "fy": 30.5, "cx": 15.5, "cy": 11.5}
    small = [{"rgb": one[0]["rgb"], "depth": np.ones((24, 32), np.float32)}]
    msg = _Error(WriteRealSenseBag(tmp_path / "x.bag", small, CAMERA, depth_camera=K_D,
                                   skip=("color_tf", "depth_tf")))
    assert "is not aligned to colour and no depth-to-colour extrinsics" in msg
    msg = _Error(WriteRos2Bag(tmp_path / "small", small, CAMERA))
    assert "depth topic /camera/aligned_depth_to_color/image_raw is 32x24, colour is 64x48" in msg
