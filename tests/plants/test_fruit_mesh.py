"""Fruit meshes from files (plant_scene.fruit.mesh_file): the plant world
places them like the procedural pepper, ground truth comes from the mesh,
and bad files are refused at load naming the key and the file."""
import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from lmap_drake.paths import DEFAULT_SCENARIO_FILE, REPO_ROOT
from lmap_drake.plants.pepper_meshes import MakeTestPepper
from lmap_drake.scenario import LoadScenario, ScenarioError

P_WC = np.array([0.5, -0.6, 0.47])


def _pepper(tmp_path, kind="blob", seed=3, scale=1.0, ext="obj", peduncle=True):
    fruit, ped = MakeTestPepper(kind, np.random.default_rng(seed), peduncle)
    fruit.apply_translation([0.01, -0.02, 0.03])       # the file's origin is ignored
    if ped is not None:
        ped.apply_translation([0.01, -0.02, 0.03])
    f = tmp_path / f"{kind}.{ext}"
    fruit.copy().apply_scale(scale).export(f)
    p = ""
    if ped is not None:
        p = tmp_path / f"{kind}.peduncle.{ext}"
        ped.copy().apply_scale(scale).export(p)
    return f, p, fruit


def _text(f, p="", **extra):
    fruit = {"mesh_file": str(f), "peduncle_file": str(p)} | extra
    return json.dumps({"plant_scene": {"fruit": fruit}})


def _load(f, p="", **extra):
    return LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_text=_text(f, p, **extra))


def test_file_fruit_ground_truth_comes_from_the_mesh(tmp_path):
    from lmap_drake.plants.generator import GeneratePlant
    f, p, fruit = _pepper(tmp_path)
    sc = _load(f, p)
    m = GeneratePlant(sc.plant_scene, P_WC)
    ref = trimesh.load(f, force="mesh")
    assert m.fruit_volume == pytest.approx(ref.volume, rel=0.01)
    assert m.fruit_mesh_W.is_watertight
    # centre = the mesh's volume centroid, carried by X_WO; axis = the file's +z
    c_W = m.X_WO[:3, :3] @ (ref.center_mass - ref.center_mass) + m.X_WO[:3, 3]
    np.testing.assert_allclose(m.fruit_center_W, c_W, atol=1e-9)
    np.testing.assert_allclose(m.fruit_mesh_W.center_mass, m.fruit_center_W, atol=1e-6)
    np.testing.assert_allclose(m.peduncle_axis_W, m.X_WO[:3, 2], atol=1e-12)
    V_O = (np.asarray(m.fruit_mesh_W.vertices) - m.X_WO[:3, 3]) @ m.X_WO[:3, :3]
    np.testing.assert_allclose(V_O, ref.vertices - ref.center_mass, atol=1e-6)
    assert m.peduncle_mesh_W is not None
    assert m.GroundTruthDict()["fruit_source"] == str(Path(f).resolve())
    # placed like the procedural pepper: beside the branch, the leaf in front, the
    # requested occlusion reached; the stalk joins the peduncle's far end to the branch
    assert m.occlusion_predicted == pytest.approx(0.85, abs=0.05) or m.occlusion_clamped
    np.testing.assert_allclose(m.stalk_W[0], m.peduncle_tip_W)
    from lmap_drake.plants.generator import MeshSignedDistance
    assert MeshSignedDistance(m.fruit_mesh_W, m.leaf_rest_W).min() > 0.003


def test_file_fruit_renders_with_fruit_and_branch_labels(tmp_path):
    from lmap_drake.labels import BRANCH, FRUIT
    from lmap_drake.plants.plant_station import GetPlantModel, RenderStill
    f, p, _ = _pepper(tmp_path, "sculpted", seed=2, ext="stl")
    sc = LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_text=[
        _text(f, p), "{plant_scene: {occlusion: 0.5}, camera_noise: {enabled: false}}"])
    _, depth, label = RenderStill(sc)
    cls = label // 100
    assert (cls == FRUIT).sum() > 300 and (cls == BRANCH).sum() > 300
    # the fruit pixels' depth matches the file mesh's ground truth position
    m = GetPlantModel(sc)
    X_WC = sc.cameras["camera0"].X_PB.GetDeterministicValue().GetAsMatrix4()
    z_C = (np.linalg.inv(X_WC) @ np.r_[m.fruit_center_W, 1.0])[2]
    assert abs(np.median(depth[cls == FRUIT]) - z_C) < 0.05


def test_small_hole_is_repaired_and_recorded(tmp_path):
    from lmap_drake.plants.fruit_mesh import LoadFruitMesh
    fruit, _ = MakeTestPepper("bent", np.random.default_rng(1), False)
    holed = fruit.copy()
    holed.update_faces(np.arange(len(holed.faces)) != 100)    # one triangle missing
    f = tmp_path / "holed.ply"
    holed.export(f)
    fm = LoadFruitMesh(str(f))
    assert fm.mesh.is_watertight and any("filled holes" in r for r in fm.repairs)
    assert fm.volume == pytest.approx(fruit.volume, rel=0.01)
    inv = fruit.copy()
    inv.invert()
    g = tmp_path / "inside_out.obj"
    inv.export(g)
    fm = LoadFruitMesh(str(g))
    assert fm.volume == pytest.approx(fruit.volume, rel=1e-6)
    assert any("outward" in r for r in fm.repairs)


@pytest.mark.parametrize("case, key, words", [
    ("millimetres", "plant_scene.fruit.mesh_file", "mesh_scale: 0.001"),
    ("empty", "plant_scene.fruit.mesh_file", "no triangles"),
    ("open", "plant_scene.fruit.mesh_file", "not watertight"),
    ("missing", "plant_scene.fruit.mesh_file", "not found"),
    ("oversized", "plant_scene.fruit.mesh_file", "0.02-0.25 m"),
    ("format", "plant_scene.fruit.mesh_file", "unsupported format"),
    ("peduncle_below", "plant_scene.fruit.peduncle_file", "top (+z) side"),
    ("peduncle_missing", "plant_scene.fruit.peduncle_file", "not found"),
])
def test_bad_fruit_meshes_are_refused_naming_key_and_file(tmp_path, case, key, words):
    f, p, fruit = _pepper(tmp_path)
    if case == "millimetres":
        f, p, _ = _pepper(tmp_path, scale=1000.0)
    elif case == "empty":
        f = tmp_path / "empty.obj"
        f.write_text("# an empty mesh\n")
    elif case == "open":                  # the top half cut away: too big a hole to guess
        half = fruit.copy()
        half.update_faces(half.triangles_center[:, 2] < half.center_mass[2])
        f = tmp_path / "open.stl"
        half.export(f)
    elif case == "missing":
        f = tmp_path / "nope.obj"
    elif case == "oversized":
        f, p, _ = _pepper(tmp_path, scale=5.0)
        p = ""
    elif case == "format":
        f = tmp_path / "pepper.glb"
        f.write_bytes(b"glTF")
    elif case == "peduncle_below":
        ped = trimesh.creation.cylinder(0.004, 0.04)
        low = fruit.vertices[np.argmin(fruit.vertices[:, 2])]
        ped.apply_translation(low - [0, 0, 0.019])        # hanging from the bottom
        p = tmp_path / "below.peduncle.obj"
        ped.export(p)
    elif case == "peduncle_missing":
        p = tmp_path / "nope.peduncle.obj"
    with pytest.raises(ScenarioError) as err:
        _load(f, p)
    msg = str(err.value)
    bad = str(p if key.endswith("peduncle_file") else f)
    assert msg.startswith(key) and Path(bad).name in msg and words in msg, msg
    assert "--scenario_text" in msg


def test_millimetre_file_loads_with_its_scale(tmp_path):
    from lmap_drake.plants.generator import GeneratePlant
    f, p, fruit = _pepper(tmp_path, scale=1000.0)
    m = GeneratePlant(_load(f, p, mesh_scale=0.001).plant_scene, P_WC)
    assert m.fruit_volume == pytest.approx(fruit.volume, rel=0.01)
