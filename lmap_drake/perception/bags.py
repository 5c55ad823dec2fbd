"""One RGB-D view from a RealSense ``.bag`` or a ROS 1 / ROS 2 bag, as numpy
arrays (read with the pure-Python ``rosbags``; no Drake here).

Sources:

- a RealSense SDK recording (a ROS 1 bag with topics
  ``/device_<d>/sensor_<s>/Color_<k>/image/data``,
  ``.../Depth_<k>/image/data``, ``.../<stream>/info/camera_info``, each
  stream's extrinsics ``.../<stream>/tf/<group>`` (``geometry_msgs/Transform``:
  the group's reference stream, the depth stream, to that stream:
  ``p_stream = R p_ref + t``), and the depth unit
  ``/device_<d>/sensor_<s>/option/Depth Units/value`` (m per raw unit));
- a ROS 1 bag (``.bag`` file) or ROS 2 bag (folder with ``metadata.yaml``)
  with ``sensor_msgs/Image`` (or ``CompressedImage``) colour, ``sensor_msgs/
  Image`` depth, ``sensor_msgs/CameraInfo`` of the colour camera; optionally
  the depth camera's ``CameraInfo`` and ``/tf_static`` (to align a depth
  image that is not aligned to colour) and ``sensor_msgs/JointState``.

Encodings: colour ``rgb8``, ``bgr8``, ``rgba8``, ``bgra8`` (or a JPEG/PNG
``CompressedImage``); depth ``16UC1`` / ``mono16`` (raw units: the RealSense
depth unit, millimetres in a ROS bag, REP 118) or ``32FC1`` (metres). A raw
0 or a non-finite value is "no return" (``inf`` in the returned depth).
"""
from __future__ import annotations

import dataclasses as dc
import io
import re
from pathlib import Path

import numpy as np

from lmap_drake.errors import InputError

TOPIC_ROLES = ("color", "depth", "info", "depth_info", "joints")
COLOR_ENCODINGS = ("rgb8", "bgr8", "rgba8", "bgra8")
DEPTH_ENCODINGS = ("16UC1", "mono16", "32FC1")
MAX_PAIR_GAP_S = 0.1     # a colour and a depth frame further apart are not a pair
ROS_DEPTH_SCALE = 0.001  # m per raw unit of a 16UC1 depth image in a ROS bag (REP 118)
UR5_JOINTS = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
              "wrist_1_joint", "wrist_2_joint", "wrist_3_joint")

_IMAGE = ("sensor_msgs/msg/Image", "sensor_msgs/Image")
_COMPRESSED = ("sensor_msgs/msg/CompressedImage", "sensor_msgs/CompressedImage")
_INFO = ("sensor_msgs/msg/CameraInfo", "sensor_msgs/CameraInfo")
_JOINTS = ("sensor_msgs/msg/JointState", "sensor_msgs/JointState")
_RS_IMAGE = re.compile(r"^/device_(\d+)/sensor_(\d+)/(Color|Depth)_(\d+)/image/data$")


class BagError(InputError):
    """A bag that cannot give one RGB-D view (unreadable, missing topics,
    mismatched sizes, unknown encodings, no camera info)."""


@dc.dataclass(frozen=True)
class BagCapture:
    """One view read from a bag. ``rgb``: HxWx4 uint8 (alpha 255); ``depth``:
    HxW float32 metres along the colour camera's optical axis, aligned to
    colour, ``inf`` = no return; ``camera``: the recording's camera dict
    (``width``, ``height``, ``fx``, ``fy``, ``cx``, ``cy`` pixels, ``serial``,
    ``depth_scale`` m per raw unit or NaN); ``t``: s from the bag's start;
    ``q``: (6,) rad from the joints topic, or None; ``source``: what was
    read (bag, kind, topics, frame index, stamps, alignment)."""
    rgb: np.ndarray
    depth: np.ndarray
    camera: dict
    t: float
    wall_time: float
    q: np.ndarray | None
    source: dict


def ParseTopics(text: str) -> dict[str, str]:
    """``"color=/a,depth=/b,info=/c"`` -> dict; raises BagError on an unknown
    role or a malformed item."""
    out = {}
    for item in filter(None, (s.strip() for s in (text or "").split(","))):
        role, sep, topic = item.partition("=")
        role, topic = role.strip(), topic.strip()
        if not sep or not topic:
            raise BagError(f"--topics: {item!r} is not ROLE=TOPIC (roles: "
                           f"{', '.join(TOPIC_ROLES)})")
        if role not in TOPIC_ROLES:
            raise BagError(f"--topics: unknown role {role!r} (roles: {', '.join(TOPIC_ROLES)})")
        out[role] = topic
    return out


def IsBag(path) -> bool:
    """A ``.bag`` file, a ROS 2 bag folder (``metadata.yaml``) or its
    ``.db3`` / ``.mcap`` file."""
    path = Path(path)
    if path.is_dir():
        return (path / "metadata.yaml").exists()
    return path.suffix in (".bag", ".db3", ".mcap")


# ------------------------------------------------------------------ decoding
def DecodeColor(msg, topic: str) -> np.ndarray:
    """HxWx4 uint8 RGBA from a ``sensor_msgs/Image`` or ``CompressedImage``."""
    if hasattr(msg, "format") and not hasattr(msg, "encoding"):      # CompressedImage
        from PIL import Image, UnidentifiedImageError
        try:
            return np.asarray(Image.open(io.BytesIO(bytes(msg.data))).convert("RGBA"))
        except (UnidentifiedImageError, OSError) as err:
            raise BagError(f"colour topic {topic}: cannot decode the compressed image "
                           f"({msg.format!r}): {err}") from None
    enc = str(msg.encoding).lower()
    if enc not in COLOR_ENCODINGS:
        raise BagError(f"colour topic {topic}: unknown encoding {msg.encoding!r} (expected "
                       f"{', '.join(COLOR_ENCODINGS)})")
    c = 4 if enc.endswith("a8") else 3
    img = _Pixels(msg, topic, np.uint8, c)
    if enc.startswith("bgr"):
        img = img[..., [2, 1, 0] + ([3] if c == 4 else [])]
    if c == 3:
        img = np.concatenate([img, np.full(img.shape[:2] + (1,), 255, np.uint8)], axis=2)
    return np.ascontiguousarray(img)


def DecodeDepth(msg, topic: str, depth_scale: float) -> np.ndarray:
    """HxW float32 metres (``inf`` = no return) from a ``sensor_msgs/Image``;
    ``depth_scale``: m per raw unit of a 16-bit image."""
    if not hasattr(msg, "encoding"):
        raise BagError(f"depth topic {topic}: a compressed depth image is not supported "
                       f"(record sensor_msgs/Image 16UC1 or 32FC1)")
    enc = str(msg.encoding)
    if enc not in DEPTH_ENCODINGS:
        raise BagError(f"depth topic {topic}: unknown encoding {enc!r} (expected "
                       f"{', '.join(DEPTH_ENCODINGS)})")
    if enc == "32FC1":
        d = _Pixels(msg, topic, np.float32, 1)[..., 0].astype(np.float32)
        d[~(np.isfinite(d) & (d > 0))] = np.inf
        return d
    raw = _Pixels(msg, topic, np.uint16, 1)[..., 0]
    d = (raw.astype(np.float64) * depth_scale).astype(np.float32)
    d[raw == 0] = np.inf
    return d


def _Pixels(msg, topic: str, dtype, channels: int) -> np.ndarray:
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    item = np.dtype(dtype).itemsize * channels
    data = np.frombuffer(bytes(msg.data), np.uint8)
    if h <= 0 or w <= 0 or step < w * item or data.size < h * step:
        raise BagError(f"topic {topic}: image data ({data.size} bytes, step {step}) does not "
                       f"hold {w}x{h} pixels of {item} bytes")
    rows = data[:h * step].reshape(h, step)[:, :w * item]
    dt = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    return rows.copy().view(dt).reshape(h, w, channels).astype(dtype)


def Intrinsics(info, topic: str) -> dict:
    """``width``, ``height``, ``fx``, ``fy``, ``cx``, ``cy`` of a CameraInfo
    (ROS 1 ``K`` or ROS 2 ``k``)."""
    K = np.asarray(getattr(info, "k", getattr(info, "K", None)), float).reshape(-1)
    if K.size != 9 or not np.all(np.isfinite(K)) or K[0] <= 0 or K[4] <= 0:
        raise BagError(f"camera info topic {topic}: no valid intrinsics K (fx, fy > 0)")
    if int(info.width) <= 0 or int(info.height) <= 0:
        raise BagError(f"camera info topic {topic}: image size {info.width}x{info.height}")
    return {"width": int(info.width), "height": int(info.height), "fx": float(K[0]),
            "fy": float(K[4]), "cx": float(K[2]), "cy": float(K[5])}


def TransformMatrix(msg) -> np.ndarray:
    """4x4 from a ``geometry_msgs/Transform`` (translation m, unit quaternion)."""
    t, q = msg.translation, msg.rotation
    x, y, z, w = float(q.x), float(q.y), float(q.z), float(q.w)
    n = np.sqrt(x * x + y * y + z * z + w * w)
    if not np.isfinite(n) or n < 1e-9:
        raise ValueError("zero or non-finite quaternion")
    x, y, z, w = x / n, y / n, z / n, w / n
    X = np.eye(4)
    X[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    X[:3, 3] = [float(t.x), float(t.y), float(t.z)]
    return X


def AlignDepthToColor(depth: np.ndarray, K_D: dict, K_C: dict, X_CD: np.ndarray) -> np.ndarray:
    """The depth image of camera D re-projected into colour camera C
    (``X_CD``: pose of D in C, ``p_C = X_CD p_D``), as the RealSense SDK's
    align does: each valid depth pixel's footprint (its corners at its depth)
    is projected into C and fills the colour pixels whose centres it covers
    (at least the nearest one); the nearest surface wins. Colour pixels no
    footprint covers are ``inf``. Returns K_C's HxW float32 metres."""
    v, u = np.nonzero(np.isfinite(depth) & (depth > 0))
    z = depth[v, u].astype(np.float64)
    R, t = X_CD[:3, :3], X_CD[:3, 3:4]

    def project(du, dv):
        p = np.stack([(u + du - K_D["cx"]) / K_D["fx"] * z,
                      (v + dv - K_D["cy"]) / K_D["fy"] * z, z])
        p = R @ p + t
        zc = np.where(p[2] > 1e-6, p[2], np.nan)
        return K_C["fx"] * p[0] / zc + K_C["cx"], K_C["fy"] * p[1] / zc + K_C["cy"], p[2]
    xc, yc, zc = project(0.0, 0.0)
    xa, ya, _ = project(-0.5, -0.5)
    xb, yb, _ = project(0.5, 0.5)
    ok = np.isfinite(xc) & np.isfinite(yc) & np.isfinite(xa + ya + xb + yb)
    xc, yc, zc, xa, ya, xb, yb = (a[ok] for a in (xc, yc, zc, xa, ya, xb, yb))
    lo_x = np.minimum(np.ceil(np.minimum(xa, xb)), np.rint(xc)).astype(np.int64)
    hi_x = np.maximum(np.ceil(np.maximum(xa, xb)) - 1, np.rint(xc)).astype(np.int64)
    lo_y = np.minimum(np.ceil(np.minimum(ya, yb)), np.rint(yc)).astype(np.int64)
    hi_y = np.maximum(np.ceil(np.maximum(ya, yb)) - 1, np.rint(yc)).astype(np.int64)
    W, H = K_C["width"], K_C["height"]
    out = np.full((H, W), np.inf)
    span_x = int(min(np.max(hi_x - lo_x, initial=0), 16)) + 1   # a footprint spans few pixels
    span_y = int(min(np.max(hi_y - lo_y, initial=0), 16)) + 1
    for dy in range(span_y):
        for dx in range(span_x):
            x, y = lo_x + dx, lo_y + dy
            m = (x <= hi_x) & (y <= hi_y) & (x >= 0) & (x < W) & (y >= 0) & (y < H)
            np.minimum.at(out, (y[m], x[m]), zc[m])
    return out.astype(np.float32)


def _SameCamera(a: dict, b: dict) -> bool:
    return (a["width"], a["height"]) == (b["width"], b["height"]) and all(
        np.isclose(a[k], b[k], rtol=0, atol=1e-6) for k in ("fx", "fy", "cx", "cy"))


# ------------------------------------------------------------------ reading
def ReadBagCapture(path, time: float | None = None, index: int | None = None,
                   topics: dict | None = None) -> BagCapture:
    """The view at ``time`` (s from the bag's start: the colour frame nearest
    to it) or colour frame ``index`` (default: the first), with the depth
    frame nearest in time; raises BagError naming the bag and the topic."""
    path = Path(path)
    if not path.exists():
        raise BagError(f"bag {path} not found")
    if time is not None and index is not None:
        raise BagError("give --time or --index, not both")
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise BagError("reading bags needs the rosbags package: pip install -e '.[bags]'") \
            from None
    bag = path.parent if path.is_file() and path.suffix in (".db3", ".mcap") else path
    try:
        reader = AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as err:  # noqa: BLE001 - rosbags raises several kinds
        raise BagError(f"bag {path} is not a readable ROS 1 / ROS 2 bag: "
                       f"{type(err).__name__}: {err}") from None
    try:
        return _Read(reader, path, time, index, dict(topics or {}))
    finally:
        reader.close()


class _Bag:
    """Reads messages of one topic (deserialised, with bag times in ns)."""

    def __init__(self, reader, path: Path):
        self.reader, self.path = reader, path
        self.types = {name: info.msgtype for name, info in reader.topics.items()}

    def Need(self, topic: str, role: str, types) -> str:
        if topic not in self.types:
            raise BagError(f"bag {self.path}: no topic {topic} ({role})")
        if self.types[topic] not in types:
            raise BagError(f"bag {self.path}: topic {topic} ({role}) is {self.types[topic]}, "
                           f"expected {types[0]}")
        return topic

    def Stamps(self, topic: str) -> list[int]:
        conns = [c for c in self.reader.connections if c.topic == topic]
        return [t for _, t, _ in self.reader.messages(connections=conns)]

    def Message(self, topic: str, k: int = 0):
        conns = [c for c in self.reader.connections if c.topic == topic]
        for i, (conn, _, raw) in enumerate(self.reader.messages(connections=conns)):
            if i == k:
                try:
                    return self.reader.deserialize(raw, conn.msgtype)
                except Exception as err:  # noqa: BLE001
                    raise BagError(f"bag {self.path}: topic {topic}: message {k} does not "
                                   f"deserialise: {err}") from None
        raise BagError(f"bag {self.path}: topic {topic} has no message {k}")

    def Nearest(self, topic: str, t_ns: int) -> tuple[int, int]:
        stamps = self.Stamps(topic)
        if not stamps:
            raise BagError(f"bag {self.path}: topic {topic} holds no messages")
        k = int(np.argmin(np.abs(np.asarray(stamps, np.int64) - t_ns)))
        return k, stamps[k]


def _Read(reader, path: Path, time, index, topics: dict) -> BagCapture:
    bag = _Bag(reader, path)
    realsense = any(_RS_IMAGE.match(t) for t in bag.types)
    found = _RealSenseTopics(bag) if realsense else _RosTopics(bag, topics)
    for role, topic in found.items():
        topics.setdefault(role, topic)
    for role in ("color", "depth", "info"):
        if role not in topics:
            raise BagError(f"bag {path}: no {role} topic found ({_Listing(bag)}); name it "
                           f"with --topics {role}=TOPIC")
    bag.Need(topics["color"], "color", _IMAGE + _COMPRESSED)
    bag.Need(topics["depth"], "depth", _IMAGE + _COMPRESSED)
    bag.Need(topics["info"], "camera info", _INFO)
    for role in ("depth_info", "joints"):
        if role in topics:
            bag.Need(topics[role], role, _INFO if role == "depth_info" else _JOINTS)
    stamps = bag.Stamps(topics["color"])
    if not stamps:
        raise BagError(f"bag {path}: colour topic {topics['color']} holds no messages")
    start = reader.start_time
    if index is not None:
        if not 0 <= index < len(stamps):
            raise BagError(f"--index {index}: colour topic {topics['color']} of {path} has "
                           f"{len(stamps)} frames (0..{len(stamps) - 1})")
        k = index
    else:
        t_ns = start + int(round((time or 0.0) * 1e9))
        if time is not None and not (start <= t_ns <= reader.end_time + MAX_PAIR_GAP_S * 1e9):
            raise BagError(f"--time {time}: the bag {path} spans 0..{reader.duration * 1e-9:.3f} s")
        k = int(np.argmin(np.abs(np.asarray(stamps, np.int64) - t_ns)))
    t_color = stamps[k]
    kd, t_depth = bag.Nearest(topics["depth"], t_color)
    gap = abs(t_depth - t_color) * 1e-9
    if gap > MAX_PAIR_GAP_S:
        raise BagError(f"bag {path}: the depth frame nearest colour frame {k} of "
                       f"{topics['color']} is {gap:.3f} s away on {topics['depth']} (more "
                       f"than {MAX_PAIR_GAP_S} s): no frame pair")
    info = Intrinsics(bag.Message(topics["info"], bag.Nearest(topics["info"], t_color)[0]),
                      topics["info"])
    rgb = DecodeColor(bag.Message(topics["color"], k), topics["color"])
    if rgb.shape[:2] != (info["height"], info["width"]):
        raise BagError(f"bag {path}: colour topic {topics['color']} is "
                       f"{rgb.shape[1]}x{rgb.shape[0]}, its camera info {topics['info']} says "
                       f"{info['width']}x{info['height']}")
    depth_msg = bag.Message(topics["depth"], kd)
    scale = _DepthScale(bag, topics["depth"]) if realsense else ROS_DEPTH_SCALE
    depth = DecodeDepth(depth_msg, topics["depth"], scale)
    depth, alignment = _Aligned(bag, topics, depth, info, realsense)
    q = None
    if "joints" in topics:
        q = _Joints(bag.Message(topics["joints"], bag.Nearest(topics["joints"], t_color)[0]),
                    topics["joints"], path)
    camera = dict(info, serial=_Serial(bag) if realsense else "",
                  depth_scale=float(scale) if str(depth_msg.encoding) != "32FC1" else float("nan"))
    source = {"bag": str(path), "kind": "realsense" if realsense else
              ("ros2" if reader.is2 else "ros1"), "topics": topics, "frame_index": k,
              "frames": len(stamps), "t": (t_color - start) * 1e-9,
              "depth_gap_s": gap, "alignment": alignment}
    return BagCapture(rgb, depth, camera, (t_color - start) * 1e-9, t_color * 1e-9, q, source)


def _Listing(bag: _Bag) -> str:
    images = sorted(t for t, ty in bag.types.items() if ty in _IMAGE + _COMPRESSED)
    return "image topics: " + (", ".join(images) if images else "none")


def _RealSenseTopics(bag: _Bag) -> dict:
    """The first Color and Depth streams of a RealSense recording."""
    out = {}
    for topic in sorted(bag.types):
        m = _RS_IMAGE.match(topic)
        if m:
            role = "color" if m.group(3) == "Color" else "depth"
            if role not in out:
                out[role] = topic
    for role, info in (("color", "info"), ("depth", "depth_info")):
        if role in out:
            name = out[role].removesuffix("/image/data") + "/info/camera_info"
            if name in bag.types:
                out[info] = name
    return out


def _RosTopics(bag: _Bag, named: dict) -> dict:
    """Colour, depth and camera info found by message type and name: a depth
    image topic has ``depth`` in its name; the camera info is the one in the
    colour topic's namespace (or the only one)."""
    images = [t for t, ty in bag.types.items() if ty in _IMAGE + _COMPRESSED]
    infos = [t for t, ty in bag.types.items() if ty in _INFO]
    joints = [t for t, ty in bag.types.items() if ty in _JOINTS]
    out = {}
    depth = [t for t in images if "depth" in t.lower()]
    color = [t for t in images if "depth" not in t.lower() and not re.search(
        r"infra|ir\b|mono|confidence", t.lower())]
    for role, cands in (("color", color), ("depth", depth)):
        if role in named:
            continue
        if len(cands) == 1:
            out[role] = cands[0]
        elif len(cands) > 1:
            pref = [t for t in cands if "aligned" in t] if role == "depth" else []
            if len(pref) == 1:
                out[role] = pref[0]
            else:
                raise BagError(f"bag {bag.path}: several {role} topics ({', '.join(sorted(cands))})"
                               f"; choose one with --topics {role}=TOPIC")
    for role, image in (("info", "color"), ("depth_info", "depth")):
        topic = named.get(image, out.get(image))
        if role in named or topic is None:
            continue
        ns = topic.rsplit("/", 2)[0] if topic.count("/") >= 2 else ""
        near = [t for t in infos if ns and t.startswith(topic.rsplit("/", 1)[0] + "/")] or \
               [t for t in infos if ns and t.startswith(ns + "/")]
        if len(near) == 1:
            out[role] = near[0]
        elif role == "info" and len(infos) == 1:
            out[role] = infos[0]
    if "depth_info" in out and out["depth_info"] == named.get("info", out.get("info")):
        del out["depth_info"]
    if "joints" not in named and len(joints) == 1:
        out["joints"] = joints[0]
    return out


def _DepthScale(bag: _Bag, depth_topic: str) -> float:
    """The RealSense depth unit (m per raw unit) of the depth sensor."""
    sensor = depth_topic.split("/")[:3]
    topic = "/".join(sensor + ["option", "Depth Units", "value"])
    if topic not in bag.types:
        raise BagError(f"bag {bag.path}: no depth unit topic {topic} (RealSense file format "
                       f"3 or later)")
    value = float(bag.Message(topic).data)
    if not (np.isfinite(value) and value > 0):
        raise BagError(f"bag {bag.path}: {topic} is {value}, not a depth unit in metres")
    return float(f"{value:.7g}")      # a Float32: drop its binary tail (0.00025, not 0.000250000012)


def _Serial(bag: _Bag) -> str:
    topic = "/device_0/info"
    if topic not in bag.types:
        return ""
    conns = [c for c in bag.reader.connections if c.topic == topic]
    for conn, _, raw in bag.reader.messages(connections=conns):
        try:
            kv = bag.reader.deserialize(raw, conn.msgtype)
        except Exception:  # noqa: BLE001 - a bad info record only loses the serial
            continue
        if getattr(kv, "key", "") == "Serial Number":
            return str(kv.value)
    return ""


def _Aligned(bag: _Bag, topics: dict, depth: np.ndarray, info: dict,
             realsense: bool) -> tuple[np.ndarray, str]:
    """The depth image in the colour camera, and how it got there."""
    if "depth_info" in topics:
        K_D = Intrinsics(bag.Message(topics["depth_info"]), topics["depth_info"])
        if depth.shape != (K_D["height"], K_D["width"]):
            raise BagError(f"bag {bag.path}: depth topic {topics['depth']} is "
                           f"{depth.shape[1]}x{depth.shape[0]}, its camera info "
                           f"{topics['depth_info']} says {K_D['width']}x{K_D['height']}")
        X_CD = _RealSenseExtrinsics(bag, topics) if realsense else _TfExtrinsics(bag, topics)
        if X_CD is None:
            if _SameCamera(K_D, info):
                return depth, "aligned (same intrinsics as colour, no extrinsics)"
            raise BagError(f"bag {bag.path}: depth {topics['depth']} is not aligned to colour "
                           f"and no depth-to-colour extrinsics were found (RealSense "
                           f".../tf/0, or /tf_static between the images' frames)")
        if _SameCamera(K_D, info) and np.allclose(X_CD, np.eye(4), rtol=0, atol=1e-9):
            return depth, "aligned (same intrinsics as colour, identity extrinsics)"
        return AlignDepthToColor(depth, K_D, info, X_CD), "re-projected into the colour camera"
    if depth.shape != (info["height"], info["width"]):
        raise BagError(f"bag {bag.path}: depth topic {topics['depth']} is "
                       f"{depth.shape[1]}x{depth.shape[0]}, colour is "
                       f"{info['width']}x{info['height']}, and there is no depth camera info "
                       f"to align it (--topics depth_info=TOPIC)")
    return depth, "aligned (as recorded)"


def _RealSenseExtrinsics(bag: _Bag, topics: dict) -> np.ndarray | None:
    """X_CD from the streams' ``tf/0`` (reference stream -> stream); a
    stream without one is the reference."""
    X = {}
    for role in ("color", "depth"):
        topic = topics[role].removesuffix("/image/data") + "/tf/0"
        if topic in bag.types:
            try:
                X[role] = TransformMatrix(bag.Message(topic))
            except (ValueError, AttributeError) as err:
                raise BagError(f"bag {bag.path}: extrinsics {topic}: {err}") from None
    if not X:
        return None
    X_CR, X_DR = X.get("color", np.eye(4)), X.get("depth", np.eye(4))
    return X_CR @ np.linalg.inv(X_DR)


def _TfExtrinsics(bag: _Bag, topics: dict) -> np.ndarray | None:
    """X_CD from ``/tf_static`` between the colour and depth images' frames."""
    if "/tf_static" not in bag.types:
        return None
    parent = {}
    for k in range(len(bag.Stamps("/tf_static"))):
        for tf in getattr(bag.Message("/tf_static", k), "transforms", []):
            parent[tf.child_frame_id.lstrip("/")] = (tf.header.frame_id.lstrip("/"),
                                                    TransformMatrix(tf.transform))

    def in_root(frame):
        X, seen = np.eye(4), set()
        while frame in parent and frame not in seen:
            seen.add(frame)
            frame, X_PF = parent[frame]
            X = X_PF @ X
        return frame, X
    c = bag.Message(topics["color"]).header.frame_id.lstrip("/")
    d = bag.Message(topics["depth"]).header.frame_id.lstrip("/")
    (rc, X_RC), (rd, X_RD) = in_root(c), in_root(d)
    if rc != rd or not c or not d:
        return None
    return np.linalg.inv(X_RC) @ X_RD


def _Joints(msg, topic: str, path: Path) -> np.ndarray:
    names = [str(n).split("/")[-1] for n in getattr(msg, "name", [])]
    pos = np.asarray(msg.position, float)
    if all(any(n.endswith(j) for n in names) for j in UR5_JOINTS) and len(names) == pos.size:
        q = np.array([pos[next(i for i, n in enumerate(names) if n.endswith(j))]
                      for j in UR5_JOINTS])
    else:
        q = pos[:6]
    if q.size != 6 or not np.all(np.isfinite(q)):
        raise BagError(f"bag {path}: joints topic {topic} does not hold 6 finite positions")
    return q
