import numpy as np
import pytest

from lmap_drake.plants.pepper import MakePepperMesh, MeshToObjText


def test_pepper_is_watertight_with_expected_size():
    mesh = MakePepperMesh((0.07, 0.07, 0.09), lobes=4)
    assert mesh.is_watertight and mesh.is_volume
    extent = mesh.bounds[1] - mesh.bounds[0]
    assert np.all(extent <= np.array([0.07, 0.07, 0.09]) + 1e-9)
    assert extent[2] > 0.08
    # Lobes remove volume relative to the bounding ellipsoid.
    ellipsoid = 4 / 3 * np.pi * 0.035 * 0.035 * 0.045
    assert 0.6 * ellipsoid < mesh.volume < ellipsoid
    np.testing.assert_allclose(mesh.center_mass, 0.0, atol=1e-9)


def test_obj_text_has_normals():
    text = MeshToObjText(MakePepperMesh(subdivisions=1))
    assert "vn " in text and "//" in text


def test_obj_text_of_a_mesh_written_before_is_its_own():
    """The kept texts are found by the mesh's content: the same mesh gives
    the same text, a moved copy its own."""
    mesh = MakePepperMesh(subdivisions=1)
    first = MeshToObjText(mesh)
    assert MeshToObjText(mesh.copy()) is first
    moved = mesh.copy().apply_translation([0.01, 0.0, 0.0])
    text = MeshToObjText(moved)
    assert text != first
    assert text.splitlines()[0] == "v " + " ".join(f"{x:.7f}" for x in moved.vertices[0])


def test_bad_parameters():
    with pytest.raises(ValueError):
        MakePepperMesh(lobe_depth=0.7)
