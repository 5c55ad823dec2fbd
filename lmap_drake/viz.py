"""Image files a person can open: RGB, colour-mapped depth, class-coloured
labels (PNG)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from lmap_drake.labels import BACKGROUND, BRANCH, FRUIT, LEAF, ROBOT, DecodeLabels

# zlib level of every PNG written: 1 encodes a noisy 640 x 480 camera frame
# in 34 ms against 233 ms at PIL's default (6), for 17 % more bytes (a
# three-fruit episode writes about 20 of them).
PNG_COMPRESS_LEVEL = 1

CLASS_COLORS = {BACKGROUND: (0, 0, 0), BRANCH: (139, 90, 43), LEAF: (40, 180, 40),
                FRUIT: (230, 30, 30), ROBOT: (90, 120, 220)}


def SavePng(image, path: str | Path) -> None:
    """Writes ``image`` (a PIL image or an HxWx3/4 uint8 array) as PNG."""
    if not isinstance(image, Image.Image):
        image = Image.fromarray(np.ascontiguousarray(image))
    image.save(path, format="PNG", compress_level=PNG_COMPRESS_LEVEL)


def RgbArray(image) -> np.ndarray:
    """HxWx3 uint8 from a Drake ImageRgba8U or an array."""
    data = np.asarray(getattr(image, "data", image))
    return np.ascontiguousarray(data[..., :3]).astype(np.uint8)


def DepthArray(image) -> np.ndarray:
    """HxW float32 metres from a Drake ImageDepth32F or an array."""
    data = np.asarray(getattr(image, "data", image), dtype=np.float32)
    return data[..., 0] if data.ndim == 3 else data


def SaveRgb(image, path: str | Path) -> None:
    SavePng(RgbArray(image), path)


def ColorizeDepth(depth: np.ndarray, near: float | None = None,
                  far: float | None = None) -> np.ndarray:
    """Turbo colour map over the finite depth range; invalid pixels black."""
    from matplotlib import colormaps

    d = DepthArray(depth)
    valid = np.isfinite(d) & (d > 0)
    out = np.zeros(d.shape + (3,), np.uint8)
    if not valid.any():
        return out
    lo = near if near is not None else float(d[valid].min())
    hi = far if far is not None else float(d[valid].max())
    t = np.clip((d - lo) / max(hi - lo, 1e-6), 0, 1)
    rgb = (colormaps["turbo"](t)[..., :3] * 255).astype(np.uint8)
    out[valid] = rgb[valid]
    return out


def SaveDepth(image, path: str | Path) -> None:
    SavePng(ColorizeDepth(image), path)


def ColorizeLabels(label_image) -> np.ndarray:
    cls, _ = DecodeLabels(np.asarray(getattr(label_image, "data", label_image)))
    out = np.zeros(cls.shape + (3,), np.uint8)
    for c, color in CLASS_COLORS.items():
        out[cls == c] = color
    return out


def SaveLabel(image, path: str | Path) -> None:
    SavePng(ColorizeLabels(image), path)
