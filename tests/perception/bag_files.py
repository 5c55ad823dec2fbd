"""Bags written by the tests with the real ``rosbags`` writers: a ROS 2 bag
(``sensor_msgs`` colour, depth and camera info, a joint state) and a
RealSense-SDK-style ROS 1 bag (``/device_0/sensor_<s>/<Stream>_0/...``
topics, ``Depth Units`` option, the streams' ``tf/0`` extrinsics), made from
one RGB-D view (numpy arrays)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

RS_COLOR = "/device_0/sensor_1/Color_0"
RS_DEPTH = "/device_0/sensor_0/Depth_0"
RS_DEPTH_UNITS = "/device_0/sensor_0/option/Depth Units/value"


def _Time(ts, t_ns: int):
    return ts.types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)


def _Header(ts, t_ns: int, frame: str, ros1: bool):
    H = ts.types["std_msgs/msg/Header"]
    return H(seq=0, stamp=_Time(ts, t_ns), frame_id=frame) if ros1 else \
        H(stamp=_Time(ts, t_ns), frame_id=frame)


def ImageMsg(ts, t_ns: int, frame: str, array: np.ndarray, encoding: str, ros1: bool):
    """A ``sensor_msgs/Image`` of ``array`` (HxW or HxWxC, little-endian)."""
    a = np.ascontiguousarray(array)
    h, w = a.shape[:2]
    return ts.types["sensor_msgs/msg/Image"](
        header=_Header(ts, t_ns, frame, ros1), height=h, width=w, encoding=encoding,
        is_bigendian=0, step=a.nbytes // h, data=np.frombuffer(a.tobytes(), np.uint8))


def CompressedMsg(ts, t_ns: int, frame: str, rgba: np.ndarray):
    """A PNG ``sensor_msgs/CompressedImage`` of the RGB of ``rgba``."""
    import io

    from PIL import Image
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgba[..., :3])).save(buf, format="PNG")
    return ts.types["sensor_msgs/msg/CompressedImage"](
        header=_Header(ts, t_ns, frame, False), format="png",
        data=np.frombuffer(buf.getvalue(), np.uint8))


def InfoMsg(ts, t_ns: int, frame: str, camera: dict, ros1: bool):
    """A ``sensor_msgs/CameraInfo`` (pinhole, no distortion) of ``camera``."""
    K = np.array([camera["fx"], 0, camera["cx"], 0, camera["fy"], camera["cy"], 0, 0, 1.0])
    P = np.array([camera["fx"], 0, camera["cx"], 0, 0, camera["fy"], camera["cy"], 0,
                  0, 0, 1.0, 0])
    roi = ts.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0,
                                                       width=0, do_rectify=False)
    fields = dict(header=_Header(ts, t_ns, frame, ros1), height=int(camera["height"]),
                  width=int(camera["width"]), distortion_model="plumb_bob",
                  binning_x=0, binning_y=0, roi=roi)
    keys = ("D", "K", "R", "P") if ros1 else ("d", "k", "r", "p")
    fields.update(zip(keys, (np.zeros(5), K, np.eye(3).ravel(), P)))
    return ts.types["sensor_msgs/msg/CameraInfo"](**fields)


def TransformMsg(ts, X: np.ndarray):
    """A ``geometry_msgs/Transform`` of the 4x4 ``X``."""
    from scipy.spatial.transform import Rotation
    x, y, z, w = Rotation.from_matrix(X[:3, :3]).as_quat()
    return ts.types["geometry_msgs/msg/Transform"](
        translation=ts.types["geometry_msgs/msg/Vector3"](x=X[0, 3], y=X[1, 3], z=X[2, 3]),
        rotation=ts.types["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w))


def WriteRos2Bag(path: Path, frames: list[dict], camera: dict, *, depth_encoding="32FC1",
                 color_encoding="rgb8", q=None, skip=(), start_ns=1_700_000_000 * 10**9,
                 period_ns=33_000_000) -> Path:
    """A ROS 2 bag with ``/camera/color/image_raw``,
    ``/camera/aligned_depth_to_color/image_raw``, ``/camera/color/camera_info``
    and (``q`` given) ``/joint_states``; ``frames``: dicts with ``rgb``
    (HxWx4 uint8) and ``depth`` (HxW float32 m, inf = no return). ``skip``:
    topics not to write (bad-bag tests)."""
    ts = get_typestore(Stores.ROS2_HUMBLE)
    png = color_encoding == "png"          # a PNG sensor_msgs/CompressedImage
    topics = {"color": ("/camera/color/image_raw/compressed" if png else
                        "/camera/color/image_raw",
                        "sensor_msgs/msg/CompressedImage" if png else "sensor_msgs/msg/Image"),
              "depth": ("/camera/aligned_depth_to_color/image_raw", "sensor_msgs/msg/Image"),
              "info": ("/camera/color/camera_info", "sensor_msgs/msg/CameraInfo"),
              "joints": ("/joint_states", "sensor_msgs/msg/JointState")}
    with Writer2(path, version=9) as w:
        conns = {role: w.add_connection(topic, typ, typestore=ts)
                 for role, (topic, typ) in topics.items()
                 if role not in skip and (role != "joints" or q is not None)}

        def put(role, t, msg):
            if role in conns:
                w.write(conns[role], t, ts.serialize_cdr(msg, topics[role][1]))
        for k, f in enumerate(frames):
            t = start_ns + k * period_ns
            put("info", t, InfoMsg(ts, t, "camera_color_optical_frame", camera, False))
            put("color", t, CompressedMsg(ts, t, "camera_color_optical_frame", f["rgb"])
                if png else ImageMsg(ts, t, "camera_color_optical_frame",
                                     _Color(f["rgb"], color_encoding), color_encoding, False))
            put("depth", t + 1000, ImageMsg(ts, t, "camera_color_optical_frame",
                                            _Depth(f["depth"], depth_encoding, 0.001),
                                            depth_encoding, False))
            if q is not None:
                put("joints", t, ts.types["sensor_msgs/msg/JointState"](
                    header=_Header(ts, t, "", False),
                    name=["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
                          "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"],
                    position=np.asarray(q, float), velocity=np.zeros(6), effort=np.zeros(6)))
    return path


def WriteRealSenseBag(path: Path, frames: list[dict], camera: dict, *, depth_camera=None,
                      X_CD=None, depth_unit=0.00025, serial="f0000001", skip=(),
                      color_encoding="rgb8", depth_encoding="mono16",
                      start_ns=1_700_000_000 * 10**9, period_ns=33_000_000) -> Path:
    """A RealSense-SDK-style ROS 1 bag: Color (sensor 1) and Depth (sensor
    0) streams with their camera info, the depth unit option, the device
    serial and the extrinsics ``tf/0`` of both streams from the reference
    (depth) stream (depth: identity; colour: ``X_CD``, default identity).
    ``frames[k]["depth"]`` is in ``depth_camera`` (default: ``camera``)."""
    ts = get_typestore(Stores.ROS1_NOETIC)
    depth_camera = depth_camera or camera
    X_CD = np.eye(4) if X_CD is None else X_CD
    T = {"color": (f"{RS_COLOR}/image/data", "sensor_msgs/msg/Image"),
         "depth": (f"{RS_DEPTH}/image/data", "sensor_msgs/msg/Image"),
         "info": (f"{RS_COLOR}/info/camera_info", "sensor_msgs/msg/CameraInfo"),
         "depth_info": (f"{RS_DEPTH}/info/camera_info", "sensor_msgs/msg/CameraInfo"),
         "color_tf": (f"{RS_COLOR}/tf/0", "geometry_msgs/msg/Transform"),
         "depth_tf": (f"{RS_DEPTH}/tf/0", "geometry_msgs/msg/Transform"),
         "units": (RS_DEPTH_UNITS, "std_msgs/msg/Float32"),
         "device": ("/device_0/info", "diagnostic_msgs/msg/KeyValue"),
         "version": ("/file_version", "std_msgs/msg/UInt32")}
    with Writer1(path) as w:
        conns = {r: w.add_connection(topic, typ, typestore=ts)
                 for r, (topic, typ) in T.items() if r not in skip}

        def put(role, t, msg):
            if role in conns:
                w.write(conns[role], t, ts.serialize_ros1(msg, T[role][1]))
        t0 = start_ns
        put("version", t0, ts.types["std_msgs/msg/UInt32"](data=4))
        put("device", t0, ts.types["diagnostic_msgs/msg/KeyValue"](key="Name",
                                                                   value="Intel RealSense L515"))
        put("device", t0, ts.types["diagnostic_msgs/msg/KeyValue"](key="Serial Number",
                                                                   value=serial))
        put("units", t0, ts.types["std_msgs/msg/Float32"](data=depth_unit))
        put("info", t0, InfoMsg(ts, t0, "", camera, True))
        put("depth_info", t0, InfoMsg(ts, t0, "", depth_camera, True))
        put("color_tf", t0, TransformMsg(ts, X_CD))
        put("depth_tf", t0, TransformMsg(ts, np.eye(4)))
        for k, f in enumerate(frames):
            t = t0 + (k + 1) * period_ns
            put("depth", t, ImageMsg(ts, t, "", _Depth(f["depth"], depth_encoding, depth_unit),
                                     depth_encoding, True))
            put("color", t + 2000, ImageMsg(ts, t, "", _Color(f["rgb"], color_encoding),
                                            color_encoding, True))
    return path


def _Color(rgba: np.ndarray, encoding: str) -> np.ndarray:
    order = {"rgb8": [0, 1, 2], "bgr8": [2, 1, 0], "rgba8": [0, 1, 2, 3],
             "bgra8": [2, 1, 0, 3]}.get(encoding, [0, 1, 2])
    return np.ascontiguousarray(rgba[..., order], np.uint8)


def _Depth(depth_m: np.ndarray, encoding: str, unit: float) -> np.ndarray:
    if encoding == "32FC1":
        return np.ascontiguousarray(depth_m, np.float32)
    raw = np.where(np.isfinite(depth_m), np.rint(depth_m / unit), 0)
    return np.clip(raw, 0, 65535).astype(np.uint16)
