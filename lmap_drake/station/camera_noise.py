"""An RGB-D sensor model like a RealSense L515 (or D4xx) for the simulated
camera: what the renderer's perfect images lack and a real user's camera has.

Functional core (``NoisyDepth``, ``NoisyColor``) on numpy images, and the
thin ``CameraNoise`` LeafSystem the simulated station puts between the
``RgbdSensor`` and its exported ``camera0.*`` ports. Parameters and the
figures behind their defaults: ``lmap_drake.station.config.CameraNoiseConfig``.

Depth (metres along the optical axis; +inf = no return, the encoding of the
hardware RealSense client, which maps every dropout to +inf):

1. incidence: the surface normal from the clean depth image; a pixel seen at
   more than ``grazing_start_deg`` from its normal loses its return with a
   probability that rises linearly to 1 at ``grazing_full_deg``;
2. thin structures: surfaces narrower than ``thin_width_px`` pixels (after
   splitting at depth jumps) lose their return with ``thin_dropout``;
3. depth edges: a pixel next to a jump larger than ``edge_jump`` takes, with
   ``mixed_pixel_fraction``, a depth drawn between its own and the far
   neighbour's (a "flying pixel"), or loses its return when the far side is
   empty;
4. noise: Gaussian with ``sigma(z) = depth_sigma_0 + depth_sigma_z2 z^2``
   per pixel, plus a spatially correlated part of ``correlated_fraction`` of
   it over ``correlated_length_px``;
5. random speckle dropouts (``speckle_dropout``), then quantisation to
   ``depth_unit``.

Colour (uint8): a per-scene lighting change (exposure gain, white balance,
a smooth brightness gradient across the image), then per-pixel shot and
read noise. Labels are not touched.

Random numbers: the lighting comes from ``seed`` only (constant over an
episode); the per-frame noise from ``seed`` and the frame's time, so a run
is reproducible and two evaluations of one frame agree.
"""
from __future__ import annotations

import dataclasses as dc

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem
from pydrake.systems.sensors import ImageDepth32F, ImageRgba8U
from scipy import ndimage

from lmap_drake.perception.points import DepthNormals
from lmap_drake.station.config import CameraNoiseConfig


def _Rng(seed: int, *extra: int) -> np.random.Generator:
    return np.random.default_rng([int(seed) & 0xFFFFFFFF, *[int(e) & 0xFFFFFFFF for e in extra]])


def IncidenceDeg(depth: np.ndarray, fx: float, fy: float, cx: float, cy: float,
                 max_jump: float) -> np.ndarray:
    """Angle (deg) between each pixel's ray and its surface normal; NaN on
    no return and across depth jumps larger than ``max_jump`` m."""
    n = DepthNormals(depth, fx, fy, cx, cy)
    v, u = np.mgrid[0:depth.shape[0], 0:depth.shape[1]]
    ray = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones(depth.shape)], axis=-1)
    ray /= np.linalg.norm(ray, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore"):
        cos = np.abs(np.sum(n * ray, axis=-1))
        ang = np.degrees(np.arccos(np.clip(cos, 0.0, 1.0)))
    ang[DepthJumps(depth, max_jump)] = np.nan
    return ang


def DepthJumps(depth: np.ndarray, jump: float, void: bool = True) -> np.ndarray:
    """Pixels with a return and a 4-neighbour whose depth differs by more than
    ``jump`` m, or (if ``void``) whose neighbour has no return."""
    d = np.where(np.isfinite(depth) & (depth > 0), depth, np.inf)
    out = np.zeros(d.shape, bool)
    with np.errstate(invalid="ignore"):
        for axis in (0, 1):
            a = np.abs(np.diff(d, axis=axis))
            n0 = np.isinf(np.take(d, range(d.shape[axis] - 1), axis=axis))
            n1 = np.isinf(np.take(d, range(1, d.shape[axis]), axis=axis))
            big = (a > jump) & ~(n0 & n1) & (void | ~(n0 | n1))
            if axis == 0:
                out[1:] |= big
                out[:-1] |= big
            else:
                out[:, 1:] |= big
                out[:, :-1] |= big
    return out & np.isfinite(d)


def ThinMask(depth: np.ndarray, width_px: float, jump: float) -> np.ndarray:
    """Pixels of surfaces narrower than ``width_px`` pixels: returns left by
    a morphological opening (disk of that diameter) of the valid mask after
    cutting it at depth jumps."""
    if width_px <= 1:
        return np.zeros(depth.shape, bool)
    valid = np.isfinite(depth) & (depth > 0)
    core = valid & ~DepthJumps(depth, jump, void=False)
    r = 0.5 * width_px
    eroded = ndimage.distance_transform_edt(core) > r
    opened = (ndimage.distance_transform_edt(~eroded) <= r) & core
    thin = core & ~opened
    # a whole surface that vanishes in the opening is thin; rims of wide
    # surfaces (the last pixel ring the opening can leave) are not
    rim = core & ~ndimage.binary_erosion(core)
    return thin & ~(rim & ndimage.binary_dilation(opened, iterations=2))


def NoisyDepth(depth: np.ndarray, K: tuple[float, float, float, float], cfg, seed: int,
               frame: int) -> np.ndarray:
    """The depth image a real L515-like sensor would give for the clean
    rendered ``depth`` (HxW metres, +inf = no return). ``K`` = (fx, fy, cx,
    cy); ``cfg`` a ``CameraNoiseConfig``. Returns float32 with +inf for every
    missing return."""
    fx, fy, cx, cy = K
    d = np.asarray(depth, dtype=np.float64)
    if d.ndim == 3:
        d = d[..., 0]
    rng = _Rng(seed, frame, 1)
    valid = np.isfinite(d) & (d > 0)
    out = np.where(valid, d, np.inf)
    drop = np.zeros(d.shape, bool)

    # 1. grazing incidence
    if cfg.grazing_full_deg > cfg.grazing_start_deg:
        # a steep surface changes depth by more than an edge jump per pixel
        # (1.3 mm across a pixel at 0.6 m is 1.3 cm in depth at 84 deg):
        # normals are taken across steps of up to 3 edge jumps
        ang = IncidenceDeg(d, fx, fy, cx, cy, 3.0 * cfg.edge_jump)
        with np.errstate(invalid="ignore"):
            p = np.clip((ang - cfg.grazing_start_deg) /
                        (cfg.grazing_full_deg - cfg.grazing_start_deg), 0.0, 1.0)
        p = np.nan_to_num(p, nan=0.0)
        drop |= rng.random(d.shape) < p
    # 2. thin structures
    if cfg.thin_dropout > 0:
        thin = ThinMask(d, cfg.thin_width_px, cfg.edge_jump)
        drop |= thin & (rng.random(d.shape) < cfg.thin_dropout)
    # 3. mixed / flying pixels at depth edges
    if cfg.mixed_pixel_fraction > 0:
        far = ndimage.maximum_filter(np.where(valid, d, np.inf), size=3)
        with np.errstate(invalid="ignore"):
            near_edge = valid & (far - d > cfg.edge_jump)
        pick = near_edge & (rng.random(d.shape) < cfg.mixed_pixel_fraction)
        to_void = pick & np.isinf(far)
        drop |= to_void
        mix = pick & ~to_void
        t = rng.random(d.shape)
        out[mix] = d[mix] + t[mix] * (far[mix] - d[mix])
    # 4. range-dependent noise, white + correlated
    sigma = cfg.depth_sigma_0 + cfg.depth_sigma_z2 * np.where(valid, d, 0.0) ** 2
    white = rng.standard_normal(d.shape)
    if cfg.correlated_fraction > 0 and cfg.correlated_length_px > 0:
        corr = ndimage.gaussian_filter(rng.standard_normal(d.shape), cfg.correlated_length_px)
        corr /= max(float(corr.std()), 1e-12)
        a = cfg.correlated_fraction
        white = np.sqrt(max(1.0 - a * a, 0.0)) * white + a * corr
    finite = np.isfinite(out)
    out[finite] += (sigma * white)[finite]
    # 5. speckle, quantisation, range limits
    if cfg.speckle_dropout > 0:
        drop |= rng.random(d.shape) < cfg.speckle_dropout
    if cfg.depth_unit > 0:
        out[np.isfinite(out)] = np.round(out[np.isfinite(out)] / cfg.depth_unit) * cfg.depth_unit
    out[drop | ~valid | ~(out > 0)] = np.inf
    return out.astype(np.float32)


def NoisyColor(rgb: np.ndarray, cfg, seed: int, frame: int) -> np.ndarray:
    """The colour image with a per-scene lighting change and per-frame sensor
    noise; ``rgb`` HxWx3 or HxWx4 uint8 (alpha kept)."""
    img = np.asarray(rgb)
    out = img.astype(np.float64)
    H, W = img.shape[:2]
    light = _Rng(seed, 7)  # per scene: constant over frames
    gain = 1.0 + light.uniform(-cfg.exposure_variation, cfg.exposure_variation)
    wb = 1.0 + light.uniform(-cfg.white_balance_variation, cfg.white_balance_variation, 3)
    direction = light.normal(size=2)
    direction /= max(np.linalg.norm(direction), 1e-12)
    v, u = np.mgrid[0:H, 0:W]
    ramp = ((u / max(W - 1, 1) - 0.5) * direction[0] + (v / max(H - 1, 1) - 0.5) * direction[1])
    shade = 1.0 + 2.0 * cfg.illumination_gradient * ramp
    out[..., :3] *= gain * wb[None, None, :] * shade[..., None]
    rng = _Rng(seed, frame, 2)
    sigma = np.sqrt(cfg.read_noise ** 2 + cfg.shot_noise ** 2 * np.clip(out[..., :3], 0, None))
    out[..., :3] += sigma * rng.standard_normal((H, W, 3))
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


def CameraProfile(cfg) -> str:
    """Short name of a ``CameraNoiseConfig`` for reports: ``ideal`` when off,
    ``l515`` with the default parameters (any ``seed_offset``: a seed, not
    a parameter of the model), ``custom`` otherwise."""
    if not cfg.enabled:
        return "ideal"
    default = CameraNoiseConfig()
    same = all(getattr(cfg, f.name) == getattr(default, f.name) for f in dc.fields(cfg)
               if f.name != "seed_offset")
    return "l515" if same else "custom"


# ----------------------------------------------------------------------------
# Drake shell.

class CameraNoise(LeafSystem):
    """Inputs ``rgb_in`` (ImageRgba8U) and ``depth_in`` (ImageDepth32F,
    metres) from an RgbdSensor; outputs ``rgb_image`` and ``depth_image``
    (same types; +inf = no return) as the sensor model of this module makes
    them. ``intrinsics`` = (fx, fy, cx, cy) px. The frame index of the noise
    is the context time in milliseconds."""

    def __init__(self, cfg, intrinsics: tuple[float, float, float, float], seed: int,
                 width: int, height: int):
        super().__init__()
        self._cfg, self._K, self._seed = cfg, tuple(intrinsics), int(seed)
        self._rgb = self.DeclareAbstractInputPort(
            "rgb_in", AbstractValue.Make(ImageRgba8U(width, height)))
        self._depth = self.DeclareAbstractInputPort(
            "depth_in", AbstractValue.Make(ImageDepth32F(width, height)))
        self.DeclareAbstractOutputPort(
            "rgb_image", lambda: AbstractValue.Make(ImageRgba8U(width, height)),
            self._calc_rgb)
        self.DeclareAbstractOutputPort(
            "depth_image", lambda: AbstractValue.Make(ImageDepth32F(width, height)),
            self._calc_depth)

    def _frame(self, context) -> int:
        return int(round(context.get_time() * 1000.0))

    def _calc_rgb(self, context, output):
        image = self._rgb.Eval(context)
        out = output.get_mutable_value()
        out.resize(image.width(), image.height())
        out.mutable_data[:] = NoisyColor(image.data, self._cfg, self._seed, self._frame(context))

    def _calc_depth(self, context, output):
        image = self._depth.Eval(context)
        out = output.get_mutable_value()
        out.resize(image.width(), image.height())
        out.mutable_data[..., 0] = NoisyDepth(image.data[..., 0], self._K, self._cfg,
                                              self._seed, self._frame(context))
