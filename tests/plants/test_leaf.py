import numpy as np
import pytest

from lmap_drake.plants.leaf import (BoundaryTriangles, ExtrudeToTets, LeafShape,
                                    MaxPrincipalStretch, OrientTets, RestShapeInverse,
                                    TetMeshToVtk, TetVolumes, TriangulateLeaf, TurnHeldLeaf)


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


def test_a_held_leaf_turns_beyond_its_petiole_and_stays_at_its_attachment():
    """A blade along +x from the attachment at the origin, grasped at 10 cm:
    a 60 deg twist about the attachment-grasp line keeps the attachment and
    the line where they are, turns the far blade rigidly (distances kept,
    its normal turned by 60 deg), and bends only near the attachment."""
    x, y = np.meshgrid(np.linspace(0.0, 0.12, 25), np.linspace(-0.03, 0.03, 7))
    blade = np.c_[x.ravel(), y.ravel(), np.zeros(x.size)]
    grasp = np.array([0.10, 0.0, 0.0])
    out, R = TurnHeldLeaf(blade, np.zeros(3), grasp, [1.0, 0.0, 0.0], np.radians(60))
    at_attach = blade[:, 0] == 0.0
    assert np.allclose(out[at_attach], blade[at_attach])
    on_line = np.abs(blade[:, 1]) < 1e-12
    assert np.allclose(out[on_line], blade[on_line])
    far = blade[:, 0] >= 0.035 + 1e-9          # beyond 0.35 of the grasp distance
    assert np.allclose(out[far], blade[far] @ R.T)
    d0 = np.linalg.norm(blade[far][:, None] - blade[far][None], axis=-1)
    d1 = np.linalg.norm(out[far][:, None] - out[far][None], axis=-1)
    assert np.allclose(d0, d1)
    assert np.degrees(np.arccos((R @ [0, 0, 1.0])[2])) == pytest.approx(60.0)
    near = (blade[:, 0] > 0) & (blade[:, 0] < 0.035) & ~on_line
    turned = np.abs(out[near][:, 2]) / np.abs(blade[near][:, 1])     # sin of the local turn
    assert np.all(turned < np.sin(np.radians(60)) - 1e-6) and np.all(turned > 0)
    # an arc about an axis across the line moves the grasp point; a pull moves it too
    out2, R2 = TurnHeldLeaf(blade, np.zeros(3), grasp, [0, 0, 1.0], np.radians(30),
                            pull_W=[0, 0, 0.02])
    g2 = out2[np.argmin(np.linalg.norm(blade - grasp, axis=1))]
    assert np.allclose(g2, R2 @ grasp + [0, 0, 0.02])
    with pytest.raises(ValueError, match="grasp away from the attachment"):
        TurnHeldLeaf(blade, np.zeros(3), np.zeros(3), [1.0, 0, 0], 1.0)
