import numpy as np
import pytest

from lmap_drake.plants.pepper import (VARIANTS, MakePepper, MakePepperMesh, PepperShape,
                                      SamplePepperShape)


@pytest.mark.parametrize("seed", range(9))
def test_sampled_peppers_are_watertight_canonical(seed):
    rng = np.random.default_rng(seed)
    shape = SamplePepperShape(rng, VARIANTS[seed % 3])
    pepper = MakePepper(shape, subdivisions=3)
    mesh = pepper.mesh
    assert mesh.is_watertight and mesh.is_volume
    np.testing.assert_allclose(mesh.center_mass, 0.0, atol=1e-9)
    extent = mesh.bounds[1] - mesh.bounds[0]
    assert np.all(extent > 0.03) and np.all(extent < 0.14)
    # The peduncle point is on the surface, on top, on the +z axis.
    p = pepper.p_O_peduncle
    assert abs(p[0]) < 1e-9 and abs(p[1]) < 1e-9
    assert p[2] > 0.6 * mesh.bounds[1][2]
    import open3d as o3d
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh(
        o3d.core.Tensor(mesh.vertices.astype(np.float32)),
        o3d.core.Tensor(mesh.faces.astype(np.int32))))
    d = scene.compute_distance(o3d.core.Tensor(p[None].astype(np.float32))).numpy()[0]
    assert d < 1e-4


def test_sampler_is_seeded_and_varied():
    a = [SamplePepperShape(np.random.default_rng(7)) for _ in range(2)]
    assert a[0] == a[1]
    rng = np.random.default_rng(0)
    shapes = [SamplePepperShape(rng) for _ in range(30)]
    assert {s.variant for s in shapes} == set(VARIANTS)
    assert {s.lobes for s in shapes} == {3, 4}
    heights = [s.size[2] for s in shapes]
    assert max(heights) - min(heights) > 0.03


def test_conical_is_narrower_at_the_bottom():
    m = MakePepper(PepperShape(cone=0.4, variant="conical"), 3).mesh
    v = m.vertices
    low = v[v[:, 2] < v[:, 2].min() + 0.015]
    high = v[v[:, 2] > v[:, 2].max() - 0.03]
    assert np.ptp(low[:, 0]) < 0.7 * np.ptp(high[:, 0])


def test_legacy_call_equals_default_shape():
    a = MakePepperMesh((0.07, 0.07, 0.09), lobes=4, subdivisions=3)
    b = MakePepper(PepperShape(size=(0.07, 0.07, 0.09)), 3).mesh
    np.testing.assert_allclose(a.vertices, b.vertices)


def test_invalid_shape():
    with pytest.raises(ValueError):
        MakePepper(PepperShape(variant="banana"))


def _angle_deg(a, b):
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a) /
                                              np.linalg.norm(b), -1, 1))))


def test_wide_family_covers_sizes_outlines_cavities_and_peduncles():
    from lmap_drake.plants.pepper import CUBE_FIT, SampleWidePepperShape  # noqa: F401
    rng = np.random.default_rng(3)
    ext, aspect, ped_len, ped_ang, offsets = [], [], [], [], []
    for _ in range(24):
        shape = SampleWidePepperShape(rng)
        pep = MakePepper(shape, subdivisions=3)
        m = pep.mesh
        assert m.is_watertight and m.is_volume
        np.testing.assert_allclose(m.center_mass, 0.0, atol=1e-9)
        assert np.abs(m.vertices).max() < CUBE_FIT          # inside the template's cube
        ext.append(m.extents.max())
        aspect.append(m.extents[2] / m.extents[:2].max())
        # The peduncle: a closed tube starting inside the fruit at the
        # attachment point and ending 0-60 deg off the axis.
        assert pep.peduncle is not None and pep.peduncle.is_watertight
        p0, tip = pep.p_O_peduncle, pep.p_O_peduncle_tip
        assert np.linalg.norm(pep.peduncle.vertices - p0, axis=1).min() < 0.006
        ped_len.append(np.linalg.norm(tip - p0))
        V = pep.peduncle.vertices
        end = V[np.linalg.norm(V - tip, axis=1) < 0.006].mean(0)
        near_end = V[np.abs(np.linalg.norm(V - tip, axis=1) - 0.012) < 0.003].mean(0)
        ped_ang.append(_angle_deg(end - near_end, [0, 0, 1]))
        offsets.append(np.linalg.norm(p0[:2]))
    ext = np.array(ext)
    assert ext.min() > 0.037 and ext.max() < 0.113 and np.ptp(ext) > 0.04
    assert min(aspect) < 0.95 and max(aspect) > 1.5          # near-round to elongated
    assert 0.008 < min(ped_len) and max(ped_len) < 0.09 and np.ptp(ped_len) > 0.03
    assert max(ped_ang) < 65 and np.ptp(ped_ang) > 25
    assert max(offsets) > 0.004                              # off-centre stem cavities


def test_new_parameters_default_to_the_old_shape():
    a = MakePepper(PepperShape(size=(0.07, 0.07, 0.09), dimple=0.2), 3)
    b = MakePepper(PepperShape(size=(0.07, 0.07, 0.09), dimple=0.2, cavity_width=0.3,
                               bend=0.0, peduncle_length=0.0), 3)
    np.testing.assert_allclose(a.mesh.vertices, b.mesh.vertices)
    assert a.peduncle is None and a.p_O_peduncle_tip is None


def test_off_axis_cavity_and_bend_move_the_attachment():
    base = PepperShape(size=(0.07, 0.07, 0.09), dimple=0.35)
    deep = MakePepper(base, 3)
    off = MakePepper(PepperShape(size=(0.07, 0.07, 0.09), dimple=0.35, cavity_offset=0.3,
                                 cavity_phase=0.0), 3)
    # The attachment is on the surface at the cavity bottom, tilted toward +x.
    assert off.p_O_peduncle[0] > 0.005 and abs(off.p_O_peduncle[1]) < 1e-3
    assert deep.p_O_peduncle[2] < 0.045 - 0.01                # the deep cavity sinks it
    import open3d as o3d
    sc = o3d.t.geometry.RaycastingScene()
    sc.add_triangles(o3d.core.Tensor(off.mesh.vertices.astype(np.float32)),
                     o3d.core.Tensor(off.mesh.faces.astype(np.uint32)))
    d = sc.compute_distance(o3d.core.Tensor(off.p_O_peduncle[None].astype(np.float32)))
    assert float(d.numpy()[0]) < 2e-3
    bent = MakePepper(PepperShape(size=(0.06, 0.06, 0.1), bend=4.0, bend_phase=np.pi / 2), 3)
    v = bent.mesh.vertices
    top, bottom = v[v[:, 2] > v[:, 2].max() - 0.01], v[v[:, 2] < v[:, 2].min() + 0.01]
    mid = v[np.abs(v[:, 2]) < 0.005]
    assert top[:, 1].mean() - mid[:, 1].mean() > 0.002      # both ends bend toward +y
    assert bottom[:, 1].mean() - mid[:, 1].mean() > 0.002
    with pytest.raises(ValueError, match="bend"):
        MakePepper(PepperShape(bend=20.0))
