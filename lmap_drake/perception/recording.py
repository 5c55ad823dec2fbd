"""What the planner saw, as an open on-disk recording, and back.

A run's ``recording/`` folder (format ``lmap_drake.recording/1``):

- ``recording.json``: ``format``; ``camera`` (``width``, ``height``, ``fx``,
  ``fy``, ``cx``, ``cy`` in pixels, ``serial``, ``depth_scale`` m per raw
  unit when known); ``X_WC`` (4x4 row-major pose of the colour camera's
  optical frame C in the world W: +z forward, +x right, +y down; metres);
  ``station`` (``simulation`` or ``hardware``); ``views``: one entry per
  captured view with ``index``, ``t`` (station time, s), ``wall_time`` (UNIX
  time, s), ``ur5_q`` (rad), ``ur5_v`` (rad/s), ``gripper`` (opening m,
  rate m/s, 1/0 the gripper reports an object, null: it cannot tell), and
  the file names below.
- ``view<k>_rgb.png``: colour, 8-bit RGBA PNG.
- ``view<k>_depth.npy``: depth along the optical axis, float32 metres,
  HxW, ``inf`` where the camera had no return (NumPy ``.npy``).
- ``view<k>_label.npy`` (simulation only): the renderer's int16 label image
  (``lmap_drake.labels``), for label-oracle replays.

Views are captured when the episode asks for them (view 0 before planning,
view 1 after the action); planning reads exactly view 0.
"""
from __future__ import annotations

import dataclasses as dc
import json
import struct
from pathlib import Path

import numpy as np

from lmap_drake.config_checks import TransformError
from lmap_drake.errors import InputError
from lmap_drake.limits import MAX_IMAGE_SIDE, MAX_RECORDING_JSON_BYTES, ReadBounded

RECORDING_FORMAT = "lmap_drake.recording/1"
RECORDING_DIR = "recording"


@dc.dataclass(frozen=True)
class CapturedView:
    """One captured view (arrays are not to be modified)."""
    index: int
    t: float
    wall_time: float
    rgb: np.ndarray                 # HxWx4 uint8
    depth: np.ndarray               # HxW float32, metres, inf = no return
    label: np.ndarray | None        # HxW int16 (simulation) or None
    q: np.ndarray                   # (6,) rad
    v: np.ndarray                   # (6,) rad/s
    gripper: np.ndarray             # (3,) opening m, rate m/s, object flag (NaN unknown)


class ViewLog(tuple):
    """An immutable tuple of ``CapturedView``s; copies share the views (it
    lives in a Drake Context, which deep-copies abstract state)."""

    def __deepcopy__(self, memo):
        return self

    def Add(self, view: CapturedView) -> "ViewLog":
        return ViewLog(tuple(self) + (view,))


@dc.dataclass
class Recording:
    views: list[CapturedView]
    camera: dict
    X_WC: np.ndarray
    station: str
    folder: Path


class RecordingError(InputError):
    """A recording folder is missing, incomplete or malformed."""


def SaveRecording(folder: Path, views, camera: dict, X_WC: np.ndarray,
                  station: str) -> list[str]:
    """Writes ``views`` to ``folder/recording/`` (see the module docstring);
    returns the written paths relative to ``folder``."""
    from lmap_drake.viz import SavePng
    out = Path(folder) / RECORDING_DIR
    out.mkdir(parents=True, exist_ok=True)
    entries, files = [], []
    for k, v in enumerate(views):
        entry = {"index": k, "t": float(v.t), "wall_time": float(v.wall_time),
                 "ur5_q": [float(x) for x in v.q], "ur5_v": [float(x) for x in v.v],
                 "gripper": [float(x) if np.isfinite(x) else None for x in v.gripper],
                 "rgb": f"view{k}_rgb.png", "depth": f"view{k}_depth.npy"}
        SavePng(np.ascontiguousarray(v.rgb, np.uint8), out / entry["rgb"])     # H x W x 4: RGBA
        np.save(out / entry["depth"], np.ascontiguousarray(v.depth, np.float32))
        if v.label is not None:
            entry["label"] = f"view{k}_label.npy"
            np.save(out / entry["label"], np.ascontiguousarray(v.label, np.int16))
        entries.append(entry)
        files += [entry[n] for n in ("rgb", "depth", "label") if n in entry]
    manifest = {"format": RECORDING_FORMAT, "station": station,
                "camera": {k: (v if isinstance(v, (str, int)) else float(v))
                           for k, v in camera.items()},
                "X_WC": np.asarray(X_WC, float).tolist(), "views": entries}
    (out / "recording.json").write_text(json.dumps(manifest, indent=1))
    return [f"{RECORDING_DIR}/{f}" for f in ["recording.json"] + files]


def _FileIn(folder: Path, name, manifest_file: Path, what: str) -> Path:
    """``folder/name`` when ``name`` is a plain relative file name that stays
    inside ``folder`` (no ``..``, no absolute path, no symlink out of it)."""
    if not isinstance(name, str) or not name:
        raise RecordingError(f"{manifest_file}: {what} file name must be a string, got {name!r}")
    p = Path(name)
    if p.is_absolute() or ".." in p.parts:
        raise RecordingError(f"{manifest_file}: {what} file {name!r} is outside the recording "
                             f"folder (file names must be relative, without '..')")
    path = folder / p
    if not path.exists():
        raise RecordingError(f"{manifest_file}: {what} file {path} is missing")
    if not path.resolve().is_relative_to(folder.resolve()):
        raise RecordingError(f"{manifest_file}: {what} file {path} is a link to "
                             f"{path.resolve()}, outside the recording folder")
    if not path.is_file():
        raise RecordingError(f"{manifest_file}: {what} file {path} is not a file")
    return path


def _ReadNpy(path: Path, shape: tuple, kinds: str, what: str) -> np.ndarray:
    """A ``.npy`` array of ``shape`` whose dtype kind is in ``kinds``,
    checked from its header before the data is read; no pickles."""
    try:
        with open(path, "rb") as f:
            version = np.lib.format.read_magic(f)
            read_header = {(1, 0): np.lib.format.read_array_header_1_0,
                           (2, 0): np.lib.format.read_array_header_2_0}.get(version)
            if read_header is None:
                raise ValueError(f".npy format version {version} is not supported")
            arr_shape, _, dtype = read_header(f)
            if dtype.hasobject:
                raise RecordingError(f"{what} {path} holds Python objects (a pickle), not "
                                     f"an image; it is not loaded")
            if tuple(arr_shape) != shape or dtype.kind not in kinds:
                raise RecordingError(f"{what} {path} is a {dtype} array of shape "
                                     f"{tuple(arr_shape)}, expected {shape}")
            f.seek(0)
            return np.load(f, allow_pickle=False)
    except RecordingError:
        raise
    except (ValueError, OSError, EOFError) as err:
        raise RecordingError(f"{what} {path} is not a NumPy .npy array file "
                             f"({' '.join(str(err).split())[:120]})") from None


def _ReadPng(path: Path, w: int, h: int) -> np.ndarray:
    """An RGBA image of ``w`` x ``h``; the size is checked from the header
    before the pixels are decoded."""
    from PIL import Image
    with open(path, "rb") as f:
        head = f.read(24)
    if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
        size = struct.unpack(">II", head[16:24])   # IHDR: width, height
        if size != (w, h):
            raise RecordingError(f"colour image {path} is {size[0]} x {size[1]} (PNG header), "
                                 f"the camera is {w} x {h}")
    try:
        with Image.open(path) as im:
            if im.size != (w, h):
                raise RecordingError(f"colour image {path} is {im.size[0]} x {im.size[1]}, "
                                     f"the camera is {w} x {h}")
            return np.asarray(im.convert("RGBA"))
    except RecordingError:
        raise
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as err:
        raise RecordingError(f"colour image {path} cannot be read: "
                             f"{' '.join(str(err).split())[:120]}") from None


def _CheckCamera(cam, manifest_file: Path) -> tuple[int, int]:
    """(width, height) of a recorded camera with sane intrinsics."""
    if not isinstance(cam, dict):
        raise RecordingError(f"{manifest_file}: camera must be a map, got {cam!r}")
    for key in ("width", "height", "fx", "fy", "cx", "cy"):
        v = cam.get(key)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
            raise RecordingError(f"{manifest_file}: camera.{key} must be a finite number, "
                                 f"got {v!r}")
    w, h = cam["width"], cam["height"]
    for key, v in (("width", w), ("height", h)):
        if v != int(v) or not 1 <= v <= MAX_IMAGE_SIDE:
            raise RecordingError(f"{manifest_file}: camera.{key} must be an integer in "
                                 f"[1, {MAX_IMAGE_SIDE}], got {v}")
    for key in ("fx", "fy"):
        if cam[key] <= 0:
            raise RecordingError(f"{manifest_file}: camera.{key} must be > 0, got {cam[key]}")
    return int(w), int(h)


def LoadRecording(run_dir) -> Recording:
    """Reads ``run_dir/recording/`` (or ``run_dir`` itself when it holds
    ``recording.json``); raises RecordingError naming the file. File names
    stay inside the folder; sizes are checked before images are decoded."""
    run_dir = Path(run_dir)
    if run_dir.exists() and not run_dir.is_dir():
        raise RecordingError(f"{run_dir} is a file, not a run folder (give the output "
                             f"folder of a run, which holds recording/)")
    folder = run_dir if (run_dir / "recording.json").exists() else run_dir / RECORDING_DIR
    manifest_file = folder / "recording.json"
    if not manifest_file.exists():
        raise RecordingError(f"no recording in {run_dir}: {manifest_file} not found (a run "
                             f"records what the planner saw in its recording/ folder)")
    if not manifest_file.is_file():
        raise RecordingError(f"{manifest_file} is not a file")
    try:
        m = json.loads(ReadBounded(manifest_file, MAX_RECORDING_JSON_BYTES, "recording file")
                       .decode("utf-8"))
    except UnicodeDecodeError:
        raise RecordingError(f"{manifest_file} is not UTF-8 text") from None
    except json.JSONDecodeError as err:
        raise RecordingError(f"{manifest_file} is not valid JSON: {err}") from None
    except OSError as err:
        raise RecordingError(f"cannot read {manifest_file}: {err.strerror or err}") from None
    if not isinstance(m, dict):
        raise RecordingError(f"{manifest_file} must hold a JSON object, got a "
                             f"{type(m).__name__}")
    if m.get("format") != RECORDING_FORMAT:
        raise RecordingError(f"{manifest_file}: format {m.get('format')!r} is not "
                             f"{RECORDING_FORMAT!r}")
    try:
        cam = m["camera"]
        w, h = _CheckCamera(cam, manifest_file)
        X_WC = np.asarray(m["X_WC"], float).reshape(4, 4)
        views = []
        if not isinstance(m["views"], list):
            raise RecordingError(f"{manifest_file}: views must be a list")
        for e in m["views"]:
            files = {key: _FileIn(folder, e[key], manifest_file, f"view {e['index']}'s {key}")
                     for key in ("rgb", "depth") + (("label",) if "label" in e else ())}
            rgb = _ReadPng(files["rgb"], w, h)
            depth = _ReadNpy(files["depth"], (h, w), "fiu", "depth image")
            label = (_ReadNpy(files["label"], (h, w), "iu", "label image")
                     if "label" in files else None)
            views.append(CapturedView(int(e["index"]), float(e["t"]), float(e["wall_time"]),
                                      rgb, depth.astype(np.float32), label,
                                      np.asarray(e["ur5_q"], float), np.asarray(e["ur5_v"], float),
                                      np.array([np.nan if x is None else x
                                                for x in e["gripper"]], float)))
    except (KeyError, TypeError, ValueError) as err:
        raise RecordingError(f"{manifest_file} is malformed: {type(err).__name__}: {err}") from None
    if not views:
        raise RecordingError(f"{manifest_file} holds no views")
    if TransformError(X_WC):      # finite and rigid (config_checks.RigidMatrixError)
        raise RecordingError(f"{manifest_file}: X_WC {TransformError(X_WC)}")
    return Recording(views, cam, X_WC, str(m.get("station", "")), folder)
