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
from pathlib import Path

import numpy as np

from lmap_drake.config_checks import TransformError
from lmap_drake.errors import InputError

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


def LoadRecording(run_dir) -> Recording:
    """Reads ``run_dir/recording/`` (or ``run_dir`` itself when it holds
    ``recording.json``); raises RecordingError naming the file."""
    from PIL import Image
    run_dir = Path(run_dir)
    folder = run_dir if (run_dir / "recording.json").exists() else run_dir / RECORDING_DIR
    manifest_file = folder / "recording.json"
    if not manifest_file.exists():
        raise RecordingError(f"no recording in {run_dir}: {manifest_file} not found (a run "
                             f"records what the planner saw in its recording/ folder)")
    try:
        m = json.loads(manifest_file.read_text())
    except json.JSONDecodeError as err:
        raise RecordingError(f"{manifest_file} is not valid JSON: {err}") from None
    if m.get("format") != RECORDING_FORMAT:
        raise RecordingError(f"{manifest_file}: format {m.get('format')!r} is not "
                             f"{RECORDING_FORMAT!r}")
    try:
        cam = m["camera"]
        w, h = int(cam["width"]), int(cam["height"])
        X_WC = np.asarray(m["X_WC"], float).reshape(4, 4)
        views = []
        for e in m["views"]:
            for key in ("rgb", "depth") + (("label",) if "label" in e else ()):
                if not (folder / e[key]).exists():
                    raise RecordingError(f"{manifest_file}: view {e['index']}'s {key} file "
                                         f"{folder / e[key]} is missing")
            rgb = np.asarray(Image.open(folder / e["rgb"]).convert("RGBA"))
            depth = np.load(folder / e["depth"])
            label = np.load(folder / e["label"]) if "label" in e else None
            if rgb.shape != (h, w, 4) or depth.shape != (h, w):
                raise RecordingError(f"{manifest_file}: view {e['index']} images are "
                                     f"{rgb.shape[:2]} / {depth.shape}, the camera is {h}x{w}")
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
