import numpy as np
import pytest

from lmap_drake.plants.leaf import (BoundaryTriangles, ExtrudeToTets, LeafShape,
                                    MaxPrincipalStretch, OrientTets, RestShapeInverse,
                                    TetMeshToVtk, TetVolumes, TriangulateLeaf)


def _area(uv, faces):
    a, b = uv[faces[:, 1]] - uv[faces[:, 0]], uv[faces[:, 2]] - uv[faces[:, 0]]
    return 0.5 * np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]).sum()


@pytest.mark.parametrize("shape", [LeafShape(), LeafShape(length=0.16, width=0.08,
                                                          shape="elliptic")])
def test_two_layer_tet_mesh(shape):
    uv, faces = TriangulateLeaf(shape)
    nodes, tets = ExtrudeToTets(uv, faces, layers=2)
    V = np.c_[nodes[:, :2], (nodes[:, 2] - 1) * shape.thickness / 2]
    tets = OrientTets(V, tets)
    vol = TetVolumes(V, tets)
    assert vol.min() > 0
    area = _area(uv, faces)
    assert vol.sum() == pytest.approx(area * shape.thickness, rel=1e-9)
    assert len(tets) == 6 * len(faces)
    # Every boundary edge of the closed surface is shared by two triangles.
    tris = BoundaryTriangles(tets)
    edges = np.sort(np.r_[tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]], axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2)
    assert TetMeshToVtk(V, tets).count("\n10") == len(tets)


def test_leaf_outline_area_matches_shape():
    s = LeafShape(length=0.12, width=0.06, shape="elliptic", element_size=0.004)
    uv, faces = TriangulateLeaf(s)
    area = _area(uv, faces)
    blade = np.pi / 4 * s.length * s.width * (8 / (3 * np.pi))  # t(1-t) profile
    petiole = s.petiole_length * s.petiole_width
    assert area == pytest.approx(blade + petiole, rel=0.08)


def test_max_principal_stretch():
    rng = np.random.default_rng(1)
    V = rng.normal(size=(4, 3))
    tets = OrientTets(V, np.array([[0, 1, 2, 3]]))
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    assert MaxPrincipalStretch(V, V @ R.T + 1.0, tets)[0] == pytest.approx(1.0)
    S = np.diag([1.1, 1.0, 0.9])
    assert MaxPrincipalStretch(V, V @ S.T, tets)[0] == pytest.approx(1.1)


def test_max_principal_stretch_is_the_largest_singular_value_with_a_stored_rest_inverse():
    rng = np.random.default_rng(2)
    V = rng.normal(size=(40, 3))
    tets = OrientTets(V, np.array([rng.choice(40, 4, replace=False) for _ in range(60)]))
    current = V + 0.1 * rng.normal(size=V.shape)
    Ds = np.stack([current[tets[:, k]] - current[tets[:, 0]] for k in (1, 2, 3)], axis=2)
    Dm = np.stack([V[tets[:, k]] - V[tets[:, 0]] for k in (1, 2, 3)], axis=2)
    svd = np.linalg.svd(Ds @ np.linalg.inv(Dm), compute_uv=False)[:, 0]
    np.testing.assert_allclose(MaxPrincipalStretch(V, current, tets), svd, rtol=1e-9)
    np.testing.assert_array_equal(MaxPrincipalStretch(V, current, tets, RestShapeInverse(V, tets)),
                                  MaxPrincipalStretch(V, current, tets))


def test_bad_shape_name():
    with pytest.raises(ValueError, match="ovate"):
        TriangulateLeaf(LeafShape(shape="round"))


def test_petiole_base_has_both_corners():
    uv, _ = TriangulateLeaf(LeafShape(element_size=0.01))
    base = uv[np.isclose(uv[:, 0], -LeafShape().petiole_length)]
    assert len(base) == 2 and np.ptp(base[:, 1]) == pytest.approx(LeafShape().petiole_width)
