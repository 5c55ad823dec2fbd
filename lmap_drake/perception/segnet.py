"""A small RGB-D segmentation network (background / branch / leaf / fruit)
trained here on randomised simulator renders (``scripts/train_segnet.py``)
and shipped as a few-hundred-kB weights file: the real-image segmenter that
finds green fruit on green leaves, where colour alone cannot.

Input (``SegNetInputs``), per pixel: colour (3, centred), a depth-return
flag (1), depth relative to the median return (1, 10 cm units, clipped) and
the surface normal in the camera frame from the smoothed depth (3). The net
is a 4-level U-Net whose finest level runs at full resolution, so class
borders follow the pixels (a heavily occluded fruit may show only a few
hundred pixels, and a one-pixel error along its border costs several points
of IoU). It is run on the bounding box of the returns within the depth cut.

Device-agnostic (torch, CPU by default); one intra-op thread as set by
``lmap_drake``.
"""
from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import torch
from scipy import ndimage
from torch import nn

from lmap_drake.errors import WeightsError
from lmap_drake.perception.points import DepthNormals

NUM_CLASSES = 4  # background, branch, leaf, fruit (lmap_drake.labels ids 0..3)
NUM_INPUTS = 8
ALIGN = 8        # spatial size multiple the U-Net needs


def SmoothedNormals(depth: np.ndarray, valid: np.ndarray, fx: float, fy: float, cx: float,
                    cy: float, sigma_px: float = 1.5) -> np.ndarray:
    """HxWx3 camera-frame unit normals (facing the camera) of the
    de-projected points after a normalised Gaussian smoothing of the depth
    over valid pixels; zeros where invalid."""
    z = np.where(valid, depth, 0.0)
    w = valid.astype(np.float64)
    zs = ndimage.gaussian_filter(z, sigma_px)
    ws = ndimage.gaussian_filter(w, sigma_px)
    with np.errstate(invalid="ignore", divide="ignore"):
        zs = np.where(valid, zs / np.maximum(ws, 1e-9), np.nan)
    n = np.nan_to_num(DepthNormals(zs, fx, fy, cx, cy), nan=0.0, posinf=0.0, neginf=0.0)
    n[~valid] = 0.0
    return n


def SegNetInputs(rgb: np.ndarray, depth: np.ndarray, K, depth_cut: float) -> np.ndarray:
    """(NUM_INPUTS, H, W) float32 network input from an RGB(A) uint8 image,
    a depth image (m; NaN/inf/0 = no return) and intrinsics ``K`` (an
    ``Intrinsics`` or (fx, fy, cx, cy))."""
    fx, fy, cx, cy = (K.fx, K.fy, K.cx, K.cy) if hasattr(K, "fx") else K
    rgb = np.asarray(rgb)[..., :3].astype(np.float32) / 255.0 - 0.5
    d = np.asarray(depth, dtype=np.float64)
    if d.ndim == 3:
        d = d[..., 0]
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(d) & (d > 0) & (d <= depth_cut)
    rel = np.zeros(d.shape)
    if valid.any():
        rel[valid] = np.clip((d[valid] - np.median(d[valid])) / 0.1, -3.0, 3.0)
    n = SmoothedNormals(d, valid, fx, fy, cx, cy)
    x = np.concatenate([rgb, valid[..., None], rel[..., None], n], axis=-1)
    return np.ascontiguousarray(x.transpose(2, 0, 1), dtype=np.float32)


def _block(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, padding=1), nn.BatchNorm2d(cout), nn.ReLU(True),
                         nn.Conv2d(cout, cout, 3, padding=1), nn.BatchNorm2d(cout), nn.ReLU(True))


class SegNet(nn.Module):
    """U-Net, channels ``widths`` per level (level 0 at full resolution).
    Outputs NUM_CLASSES class logits and, with ``boundary_head``, one more
    channel: the logit of "two leaves meet here" (``labels.LeafBoundaryMask``
    of the truth leaves), which flush blades need (``perception.leaf_boundaries``)."""

    def __init__(self, widths: tuple[int, ...] = (12, 24, 48, 64), boundary_head: bool = False):
        super().__init__()
        self.widths = tuple(int(w) for w in widths)
        self.boundary_head = bool(boundary_head)
        w = self.widths
        self.enc = nn.ModuleList([_block(NUM_INPUTS if i == 0 else w[i - 1], w[i])
                                  for i in range(len(w))])
        self.up = nn.ModuleList([nn.ConvTranspose2d(w[i + 1], w[i], 2, stride=2)
                                 for i in range(len(w) - 1)])
        self.dec = nn.ModuleList([_block(2 * w[i], w[i]) for i in range(len(w) - 1)])
        self.head = nn.Conv2d(w[0], NUM_CLASSES + int(self.boundary_head), 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for i, enc in enumerate(self.enc):
            x = enc(x if i == 0 else nn.functional.max_pool2d(x, 2))
            skips.append(x)
        x = skips[-1]
        for i in reversed(range(len(self.dec))):
            x = self.dec[i](torch.cat([self.up[i](x), skips[i]], dim=1))
        return self.head(x)


def SaveSegNet(net: SegNet, path: str | Path, meta: dict) -> None:
    torch.save({"widths": list(net.widths), "boundary_head": net.boundary_head,
                "state_dict": net.state_dict(), "meta": meta}, str(path))


class SegNetWeightsError(WeightsError):
    """The segmentation network's weights file is missing or unreadable."""


def LoadSegNet(path: str | Path, device: str = "cpu") -> SegNet:
    """The network stored by ``SaveSegNet`` (eval mode); a clear error
    naming the file when it is missing or not such a file."""
    path = Path(path)
    if not path.is_file():
        raise SegNetWeightsError(
            f"segmentation network weights not found: {path} (perception.segnet_weights); "
            f"make them with 'python scripts/train_segnet.py'")
    try:
        blob = torch.load(str(path), map_location=device, weights_only=True)
        net = SegNet(tuple(blob["widths"]), bool(blob.get("boundary_head", False)))
        net.load_state_dict(blob["state_dict"])
    except pickle.UnpicklingError as err:   # never executed: weights_only=True
        first = " ".join(str(err).split("\n\n")[-1].split())[:160]
        raise SegNetWeightsError(
            f"refusing {path} (perception.segnet_weights): it holds pickled Python objects "
            f"other than tensors, which are never loaded (weights_only=True; {first})") from None
    except Exception as err:
        raise SegNetWeightsError(f"could not read segmentation network weights {path}: "
                                 f"{type(err).__name__}: {err}") from err
    net.meta = blob.get("meta", {})
    return net.to(device).eval()


def _Pad(x: np.ndarray, align: int) -> tuple[np.ndarray, tuple[int, int]]:
    H, W = x.shape[-2:]
    ph, pw = (-H) % align, (-W) % align
    return np.pad(x, ((0, 0), (0, ph), (0, pw))), (H, W)


@torch.no_grad()
def PredictLogits(net: SegNet, inputs: np.ndarray, device: str = "cpu") -> np.ndarray:
    """(NUM_CLASSES [+ 1 boundary], H, W) logits for a (NUM_INPUTS, H, W)
    input of any size."""
    x, (H, W) = _Pad(inputs, ALIGN)
    y = net(torch.from_numpy(x)[None].to(device))[0, :, :H, :W]
    return y.cpu().numpy()


def CropBox(valid: np.ndarray, margin: int = 16) -> tuple[slice, slice] | None:
    """Bounding box (rows, cols) of ``valid`` grown by ``margin`` px; None
    when nothing is valid."""
    rows, cols = np.nonzero(valid)
    if len(rows) == 0:
        return None
    H, W = valid.shape
    return (slice(max(rows.min() - margin, 0), min(rows.max() + margin + 1, H)),
            slice(max(cols.min() - margin, 0), min(cols.max() + margin + 1, W)))
