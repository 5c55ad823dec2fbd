import numpy as np
import torch
import trimesh

from lmap_drake.shape.config import ShapeConfig
from lmap_drake.shape.deepsdf import DecoderSdf, LoadDecoder
from lmap_drake.shape.marching import ExtractIsoSurface
from lmap_drake.shape.metrics import (AngleErrorDeg, CenterErrorCm, ChamferCm, MeshCentroid,
                                      MeshVolume, ShapeMetrics)


def _sphere(r, c=(0, 0, 0)):
    m = trimesh.creation.icosphere(subdivisions=5, radius=r)
    m.apply_translation(c)
    return m.vertices, m.faces


def _expected_offset_chamfer_cm(r, d):
    # Mean over sphere A (uniform: cos(theta) uniform in [-1, 1]) of the
    # distance to sphere B of the same radius, centre offset by d.
    x = np.linspace(-1, 1, 200001)
    dist = np.abs(np.sqrt(r * r + d * d - 2 * r * d * x) - r)
    return 100 * dist.mean()  # both directions are equal by symmetry


def test_two_spheres_offset_by_one_cm():
    r = 0.04
    va, fa = _sphere(r)
    vb, fb = _sphere(r, (0.01, 0, 0))
    m = ShapeMetrics(va, fa, [0, 0, 1], vb, fb, [0, 0, 1], n=30000)
    assert abs(m["center_err_cm"] - 1.0) < 0.01
    assert m["volume_err_cm3"] < 0.5
    assert m["angle_err_deg"] < 1e-6
    assert abs(m["chamfer_cm"] - _expected_offset_chamfer_cm(r, 0.01)) < 0.03


def test_concentric_spheres_volume_and_chamfer():
    va, fa = _sphere(0.04)
    vb, fb = _sphere(0.05)
    m = ShapeMetrics(va, fa, [0, 0, 1], vb, fb, [1, 0, 0], n=20000)
    assert abs(m["volume_err_cm3"] - 4 / 3 * np.pi * (125 - 64)) < 3.0
    assert abs(m["chamfer_cm"] - 1.0) < 0.02
    assert m["center_err_cm"] < 0.01
    assert abs(m["angle_err_deg"] - 90) < 1e-6


def test_basic_functions():
    assert abs(AngleErrorDeg([0, 0, 1], [0, 1, 1]) - 45) < 1e-9
    assert abs(CenterErrorCm([0, 0, 0], [0.03, 0.04, 0]) - 5.0) < 1e-9
    p = np.random.default_rng(0).normal(size=(100, 3))
    assert ChamferCm(p, p) == 0.0
    assert ChamferCm(p, p + [0.01, 0, 0]) > 0.5 * 0.99


def test_box_volume_centroid_and_marching_is_watertight():
    box = trimesh.creation.box(extents=(0.02, 0.04, 0.06))
    box.apply_translation((0.1, 0, 0))
    assert abs(MeshVolume(box.vertices, box.faces) - 0.02 * 0.04 * 0.06) < 1e-12
    np.testing.assert_allclose(MeshCentroid(box.vertices, box.faces), [0.1, 0, 0], atol=1e-12)
    v, f = ExtractIsoSurface(lambda p: np.linalg.norm(p, axis=1) - 0.03, [-0.03] * 3,
                             [0.03] * 3, 0.002)
    m = trimesh.Trimesh(v, f, process=False)
    assert m.is_watertight and m.is_winding_consistent
    assert abs(MeshVolume(v, f) / (4 / 3 * np.pi * 0.03 ** 3) - 1) < 0.01
    assert m.volume > 0  # outward winding


def test_narrow_band_extraction_gives_the_same_mesh_from_fewer_samples():
    """``band``: coarse samples first, fine ones only near the surface; the
    mesh equals the full grid's (two spheres, one cut into the other)."""
    def sdf(p):
        a = np.linalg.norm(p - [0.01, 0, 0], axis=1) - 0.03
        b = np.linalg.norm(p - [-0.025, 0.01, 0.02], axis=1) - 0.012
        return np.maximum(a, -b)
    calls = []

    def counted(p):
        calls.append(len(p))
        return sdf(p)
    lo, hi, h = [-0.045, -0.05, -0.05], [0.06, 0.05, 0.05], 0.0021   # 1.5 cm margin
    _AssertBandGivesTheFullMesh(counted, calls, lo, hi, h, band=4 * h)


def _AssertBandGivesTheFullMesh(sdf, calls: list, lo, hi, h: float, band: float):
    """The mesh refined within ``band`` of the surface equals the full
    grid's, from under 60 % of its samples (``sdf`` appends each call's
    point count to ``calls``)."""
    calls.clear()
    v_full, f_full = ExtractIsoSurface(sdf, lo, hi, h, band=1e9)
    n_full = sum(calls)
    calls.clear()
    v, f = ExtractIsoSurface(sdf, lo, hi, h, band=band)
    np.testing.assert_array_equal(f, f_full)
    np.testing.assert_array_equal(v, v_full)
    assert sum(calls) < 0.6 * n_full, (sum(calls), n_full)


def test_the_two_cell_band_gives_the_full_grids_mesh_of_the_template():
    """The fruit and hypothesis meshes are refined within 2 cells of the
    surface (``band=2 * h``): on the shipped template (the mean shape and a
    training latent, at the fit's 3 mm and the hypotheses' 5 mm in W at
    scales 1 and 1.4) the mesh is the full grid's, from fewer samples."""
    torch.set_num_threads(1)
    dec, mean, extra = LoadDecoder(ShapeConfig().weights_file)
    for z in (mean, extra["train_latents"].numpy()[2]):
        zt = torch.as_tensor(np.asarray(z, np.float32))
        calls = []

        def sdf(p):
            calls.append(len(p))
            with torch.no_grad():
                return DecoderSdf(dec, zt, torch.as_tensor(p, dtype=torch.float32)).numpy()
        lo, hi = np.full(3, -0.06), np.full(3, 0.06)
        for spacing, s in ((0.003, 1.0), (0.005, 1.4)):
            h = spacing / s
            _AssertBandGivesTheFullMesh(sdf, calls, lo, hi, h, band=2 * h)
