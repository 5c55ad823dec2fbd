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
