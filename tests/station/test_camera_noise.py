"""The simulated camera's sensor model (lmap_drake/station/camera_noise.py):
functional core on synthetic depth images, and its place in the station."""
import dataclasses as dc

import numpy as np
import pytest

from lmap_drake.scenario import LoadScenario
from lmap_drake.station.config import CameraNoiseConfig
from lmap_drake.station.camera_noise import (CameraProfile, IncidenceDeg, NoisyColor,
                                             NoisyDepth, ThinMask)

K = (450.0, 450.0, 160.0, 120.0)
H, W = 240, 320


def _only(**kw) -> CameraNoiseConfig:
    """A config with every effect off except those given."""
    off = dict(depth_sigma_0=0.0, depth_sigma_z2=0.0, correlated_fraction=0.0,
               grazing_start_deg=90.0, grazing_full_deg=90.0, thin_dropout=0.0,
               mixed_pixel_fraction=0.0, speckle_dropout=0.0, depth_unit=0.0)
    off.update(kw)
    return dc.replace(CameraNoiseConfig(), **off)


def _plane(z: float) -> np.ndarray:
    return np.full((H, W), z, np.float32)


@pytest.mark.parametrize("z", [0.5, 1.0])
def test_depth_noise_grows_with_range_as_configured(z):
    cfg = _only(depth_sigma_0=0.001, depth_sigma_z2=0.002)
    d = NoisyDepth(_plane(z), K, cfg, seed=1, frame=0)
    expected = 0.001 + 0.002 * z * z
    assert np.isfinite(d).all()
    assert abs(float(np.std(d - z)) - expected) < 0.1 * expected
    assert abs(float(np.mean(d - z))) < 0.1 * expected


def test_default_noise_is_one_to_three_mm_at_half_a_metre():
    d = NoisyDepth(_plane(0.5), K, CameraNoiseConfig(), seed=2, frame=0)
    err = d[np.isfinite(d)] - 0.5
    assert 0.001 <= float(np.std(err)) <= 0.003


def test_grazing_surfaces_lose_their_returns_frontal_ones_do_not():
    cfg = _only(grazing_start_deg=72.0, grazing_full_deg=86.0)
    frontal = NoisyDepth(_plane(0.6), K, cfg, 0, 0)
    assert np.isfinite(frontal[2:-2, 2:-2]).mean() > 0.999
    # a plane turned 84 deg away from the camera (depth grows along x fast)
    v, u = np.mgrid[0:H, 0:W]
    x = (u - K[2]) / K[0]
    tan = np.tan(np.radians(84.0))
    z = 0.6 / (1.0 - x * tan)  # plane z = 0.6 + tan * X through (0, 0, 0.6)
    z = np.where((z > 0.2) & (z < 3.0), z, np.inf).astype(np.float32)
    ang = IncidenceDeg(z, *K, max_jump=0.05)
    assert np.nanmedian(ang[:, 150:170]) > 80.0
    glancing = NoisyDepth(z, K, cfg, 0, 0)
    kept = np.isfinite(glancing[:, 150:170]).mean()
    assert kept < 0.4


def test_thin_structures_lose_returns():
    d = np.full((H, W), np.inf, np.float32)
    d[:, 100:102] = 0.6      # a 2 px twig
    d[:, 200:240] = 0.6      # a 40 px branch
    thin = ThinMask(d, 3.0, 0.01)
    assert thin[:, 100:102].mean() > 0.95 and thin[5:-5, 205:235].mean() == 0.0
    out = NoisyDepth(d, K, _only(thin_dropout=0.5), 3, 0)
    assert 0.35 < (~np.isfinite(out[:, 100:102])).mean() < 0.65
    assert np.isfinite(out[5:-5, 205:235]).all()


def test_mixed_pixels_lie_between_the_surfaces_of_an_edge():
    d = _plane(1.0)
    d[:, :160] = 0.5
    out = NoisyDepth(d, K, _only(mixed_pixel_fraction=1.0), 4, 0)
    edge = out[:, 159]  # the near side of the jump
    assert ((edge > 0.5) & (edge < 1.0)).mean() > 0.95
    assert np.all(out[:, :150] == 0.5) and np.all(out[:, 170:] == 1.0)


def test_quantisation_and_reproducibility():
    cfg = CameraNoiseConfig()
    a = NoisyDepth(_plane(0.7), K, cfg, 5, 10)
    b = NoisyDepth(_plane(0.7), K, cfg, 5, 10)
    c = NoisyDepth(_plane(0.7), K, cfg, 5, 11)
    f = np.isfinite(a)
    assert np.array_equal(a, b, equal_nan=True)
    assert not np.array_equal(a[f & np.isfinite(c)], c[f & np.isfinite(c)])
    q = a[f] / cfg.depth_unit
    assert np.abs(q - np.round(q)).max() < 1e-2


def test_colour_noise_is_mild_and_lighting_is_fixed_per_scene():
    rgb = np.full((H, W, 4), 120, np.uint8)
    cfg = CameraNoiseConfig()
    a = NoisyColor(rgb, cfg, 1, 0).astype(float)
    b = NoisyColor(rgb, cfg, 1, 1).astype(float)
    assert a.shape == rgb.shape and np.all(a[..., 3] == 120)
    diff = a[..., :3] - b[..., :3]
    assert 1.5 < diff.std() / np.sqrt(2) < 4.0            # per-pixel noise, a few levels
    assert abs(diff.mean()) < 0.5                          # same lighting in both frames
    gain = a[..., :3].mean() / 120.0
    assert 0.7 < gain < 1.3


def test_station_applies_the_model_and_enabled_false_gives_the_renderer_images():
    from lmap_drake.plants.plant_station import MakePlantStation
    from lmap_drake.plants.plant_station import RenderStill

    def render(text):
        s = LoadScenario(scenario_text=text)
        has_noise = any(sys.get_name() == "camera_noise_camera0"
                        for sys in MakePlantStation(s).GetSystems())
        rgb, depth, _ = RenderStill(s)
        return depth, rgb, has_noise

    clean_d, clean_rgb, noisy_flag0 = render("{camera_noise: {enabled: false}}")
    noisy_d, noisy_rgb, noisy_flag1 = render("{}")
    assert not noisy_flag0 and noisy_flag1
    both = np.isfinite(clean_d) & np.isfinite(noisy_d)
    assert both.sum() > 1000
    err = noisy_d[both] - clean_d[both]
    assert 0.0005 < float(np.median(np.abs(err))) < 0.01
    assert (np.isfinite(clean_d) & ~np.isfinite(noisy_d)).sum() > 0   # some dropouts
    assert not np.array_equal(clean_rgb, noisy_rgb)
    assert CameraProfile(CameraNoiseConfig()) == "l515"
    assert CameraProfile(CameraNoiseConfig(enabled=False)) == "ideal"
    assert CameraProfile(CameraNoiseConfig(depth_unit=0.001)) == "custom"


def test_every_dropout_lies_within_perception_no_return_margin_of_a_return():
    """``perception.no_return_margin_px`` keeps no-return pixels next to a
    return from carving free space (they may be this camera's dropouts, a
    surface there): the default must cover every dropout the default camera
    model makes, here in the default scene's first view, and not be far
    wider (it also withholds the free space beside every silhouette)."""
    from scipy import ndimage

    from lmap_drake.plants.plant_station import RenderStill
    s = LoadScenario()
    _, clean_d, _ = RenderStill(LoadScenario(scenario_text="{camera_noise: {enabled: false}}"))
    _, noisy_d, _ = RenderStill(s)
    dropped = np.isfinite(clean_d) & ~np.isfinite(noisy_d)
    assert dropped.sum() > 100
    to_return = ndimage.distance_transform_edt(~np.isfinite(noisy_d))
    band = float(to_return[dropped].max())
    assert band <= s.perception.no_return_margin_px <= 2.0 * band
