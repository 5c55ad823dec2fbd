"""Plants from mesh files (``plant_scene.kind: mesh_plant``): a small plant
written with trimesh in tmp_path (a stem, a stalk, a fruit, an alpha-card
leaf in front of the fruit, a plain leaf, a PLY leaf) loads; the card is cut
to its alpha outline; bad files fail at scenario load with one line naming
the file and the key (exit code 2 on the CLI); the leaf hiding the fruit
becomes the FEM slab; the scene builds in the station and renders leaf,
fruit and branch labels."""
import numpy as np
import pytest
import trimesh
from PIL import Image

from lmap_drake.cli import main
from lmap_drake.labels import BRANCH, FRUIT, LEAF, DecodeLabels
from lmap_drake.plants.leaf import TetVolumes
from lmap_drake.plants.mesh_plant_files import LoadMeshPlantParts
from lmap_drake.plants.plant_station import GetPlantModel, RenderStill, UnoccludedFruitPixels
from lmap_drake.scenario import LoadScenario, ScenarioError

FRUIT_C = np.array([0.045, -0.005, 0.30])      # plant frame (origin at the base), m
CARD_X, CARD_Z = (0.035, 0.145), (0.24, 0.37)   # the card's extent, in the plane y = -0.07
ELLIPSE = (0.045, 0.055)                       # the alpha ellipse's half axes (x, z), m


def _card(path, opaque=False):
    """A quad card in front of the fruit (camera0 looks along +y) with an
    RGBA texture: an ellipse of alpha 255 (everywhere with ``opaque``)."""
    x0, x1 = CARD_X
    z0, z1 = CARD_Z
    V = np.array([[x0, -0.07, z0], [x1, -0.07, z0], [x1, -0.07, z1], [x0, -0.07, z1]])
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1.0]])
    n = 200
    yy, xx = np.mgrid[0:n, 0:n]
    px, pz = (xx + 0.5) / n * (x1 - x0), (1 - (yy + 0.5) / n) * (z1 - z0)
    cx, cz = (x1 - x0) / 2, (z1 - z0) / 2
    inside = ((px - cx) / ELLIPSE[0]) ** 2 + ((pz - cz) / ELLIPSE[1]) ** 2 <= 1
    rgba = np.zeros((n, n, 4), np.uint8)
    rgba[..., :3] = (40, 120, 30)
    rgba[..., 3] = 255 if opaque else np.where(inside, 255, 0)
    mat = trimesh.visual.material.SimpleMaterial(image=Image.fromarray(rgba, "RGBA"))
    mesh = trimesh.Trimesh(V, [[0, 1, 2], [0, 2, 3]], process=False,
                           visual=trimesh.visual.TextureVisuals(uv=uv, material=mat))
    mesh.export(path)


def _ellipse_leaf(center, a, b, normal_axis=2, n=24):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ring = np.c_[a * np.cos(t), b * np.sin(t)]
    pts = np.vstack([[0, 0], ring])
    V = np.insert(pts, normal_axis, 0.0, axis=1) + center
    F = [[0, 1 + k, 1 + (k + 1) % n] for k in range(n)]
    return trimesh.Trimesh(V, F, process=False)


def WritePlant(folder, fruit_scale=1.0, card_opaque=False):
    """The small test plant in ``folder`` (subfolder layout)."""
    for sub in ("stems", "leaves", "fruits"):
        (folder / sub).mkdir(parents=True, exist_ok=True)
    stem = trimesh.creation.cylinder(0.006, segment=[[0, 0, 0], [0, 0, 0.5]])
    stem.export(folder / "stems" / "main.obj")
    top = FRUIT_C + [0, 0, 0.038]
    trimesh.creation.cylinder(0.003, segment=[top - [0, 0, 0.004], [0.0, 0, 0.36]]).export(
        folder / "stems" / "stalk.ply")
    fruit = trimesh.creation.icosphere(subdivisions=3)
    fruit.apply_scale([0.034, 0.034, 0.04])
    fruit.apply_translation(FRUIT_C)
    fruit.apply_scale(fruit_scale)
    fruit.export(folder / "fruits" / "pepper.obj")
    _card(folder / "leaves" / "card.obj", card_opaque)
    _ellipse_leaf([-0.07, 0.0, 0.2], 0.06, 0.03).export(folder / "leaves" / "plain.obj")
    _ellipse_leaf([-0.05, 0.01, 0.42], 0.05, 0.025, 1).export(folder / "leaves" / "high.ply")
    return folder


def _scenario(folder, **extra):
    more = "".join(f", {k}: {v}" for k, v in extra.items())
    return LoadScenario(scenario_text=[
        "{plant_scene: {kind: mesh_plant, mesh_plant: {folder: '%s'%s}}}" % (folder, more)])


@pytest.fixture(scope="module")
def plant(tmp_path_factory):
    return WritePlant(tmp_path_factory.mktemp("plant"))


def test_plant_folder_loads(plant):
    s = _scenario(plant)
    parts = LoadMeshPlantParts(s.plant_scene.mesh_plant)
    assert sorted(p.kind for p in parts) == ["fruit", "leaf", "leaf", "leaf", "stem", "stem"]
    card = next(p for p in parts if p.name == "card")
    plain = next(p for p in parts if p.name == "plain")
    assert card.card and card.image is not None and not plain.card
    fruit = next(p for p in parts if p.kind == "fruit")
    np.testing.assert_allclose(fruit.mesh.center_mass, FRUIT_C, atol=1e-4)


def test_alpha_card_is_cut_to_its_outline(plant, tmp_path):
    parts = LoadMeshPlantParts(_scenario(plant).plant_scene.mesh_plant)
    sheet = next(p for p in parts if p.name == "card").sheet
    ellipse = np.pi * ELLIPSE[0] * ELLIPSE[1]
    assert abs(sheet.area - ellipse) / ellipse < 0.03, (sheet.area, ellipse)
    # the outline, mapped onto the card, is the ellipse in the card's plane
    P = sheet.Map(sheet.outline)
    np.testing.assert_allclose(P[:, 1], -0.07, atol=1e-9)
    r = ((P[:, 0] - np.mean(CARD_X)) / ELLIPSE[0]) ** 2 + \
        ((P[:, 2] - np.mean(CARD_Z)) / ELLIPSE[1]) ** 2
    assert np.all(np.abs(r - 1) < 0.08), r.min()
    # a card of a leaf atlas: only the part of the texture its uv cover counts
    from lmap_drake.plants.mesh_plant_leaves import CardSheet
    atlas = np.zeros((100, 200, 4), np.uint8)
    yy, xx = np.mgrid[0:100, 0:200]
    atlas[..., 3] = np.where((xx - 50) ** 2 + (yy - 50) ** 2 <= 30 ** 2, 255, 0)    # small leaf
    atlas[10:95, 105:195, 3] = 255                                                  # big one
    V = np.array([[0, 0, 0], [0.1, 0, 0], [0.1, 0, 0.1], [0, 0, 0.1]])
    uv = np.array([[0, 0], [0.5, 0], [0.5, 1], [0, 1.0]])                 # the left half
    sheet = CardSheet(V, [[0, 1, 2], [0, 2, 3]], uv, Image.fromarray(atlas, "RGBA"), 0.5)
    assert abs(sheet.area - np.pi * 0.03 ** 2) / (np.pi * 0.03 ** 2) < 0.03, sheet.area
    # a card without transparent pixels is not cut: the whole quad
    opaque = WritePlant(tmp_path / "opaque", card_opaque=True)
    parts = LoadMeshPlantParts(_scenario(opaque).plant_scene.mesh_plant)
    card = next(p for p in parts if p.name == "card")
    assert not card.card
    quad = (CARD_X[1] - CARD_X[0]) * (CARD_Z[1] - CARD_Z[0])
    assert abs(card.sheet.area - quad) < 1e-9


def test_fem_leaf_is_the_occluder(plant):
    s = _scenario(plant, max_fem_leaves=1)
    model = GetPlantModel(s)
    assert len(model.leaves) == 1 and model.num_leaves_total == 3
    assert model.leaf_sources[0].endswith("card.obj")
    f = model.fruits[0]
    assert f.occluders[:1] == [0] and f.occlusion_predicted > 0.25
    base = np.array([0.5, 0.0, 0.1])
    np.testing.assert_allclose(f.center_W, FRUIT_C + base, atol=1e-4)
    assert abs(f.volume - 4 / 3 * np.pi * 0.034 ** 2 * 0.04) / f.volume < 0.03
    assert f.peduncle_axis_W @ [0, 0, 1] > 0.99           # the stalk enters at the top
    leaf = model.leaves[0]
    assert np.all(TetVolumes(leaf.rest_W, leaf.tets) > 0)
    assert 250 <= len(leaf.tets) <= 1000                   # about fem_target_tets (500)
    fixed = leaf.rest_W[leaf.fixed]
    assert len(fixed) >= 3 and np.linalg.norm(fixed.mean(0)[:2] - base[:2]) < \
        np.linalg.norm(leaf.rest_W.mean(0)[:2] - base[:2])          # at the stem's end
    np.testing.assert_allclose(np.ptp(leaf.rest_W[:, 1]), 0.002, atol=1e-6)   # 2 mm slab
    gt = model.GroundTruthDict()
    assert gt["kind"] == "mesh_plant" and gt["fruits"][0]["name"] == "pepper"
    assert [lf["fem"] for lf in gt["leaves"]] == [True, False, False]


def test_named_parts_in_one_glb_y_up(tmp_path):
    scene = trimesh.Scene()
    z_to_y = np.array([[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1.0]])
    stem = trimesh.creation.cylinder(0.006, segment=[[0, 0, 0], [0, 0, 0.5]])
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.035)
    V = sphere.triangles.reshape(-1, 3)                   # textured, unwelded (as STL)
    uv = np.c_[np.arctan2(V[:, 1], V[:, 0]) / (2 * np.pi) + 0.5, V[:, 2] / 0.07 + 0.5]
    fruit = trimesh.Trimesh(V + FRUIT_C, np.arange(len(V)).reshape(-1, 3), process=False,
                            visual=trimesh.visual.TextureVisuals(
                                uv=uv, material=trimesh.visual.material.SimpleMaterial(
                                    image=Image.new("RGB", (8, 8), (200, 30, 20)))))
    leaf = _ellipse_leaf([-0.07, 0.0, 0.2], 0.06, 0.03)
    for name, m in (("Stem_main", stem), ("leaf.001", leaf), ("fruit_a", fruit),
                    ("ignore_pot", trimesh.creation.box([0.1, 0.1, 0.1]))):
        scene.add_geometry(m.copy().apply_transform(z_to_y), node_name=name, geom_name=name)
    scene.export(tmp_path / "plant.glb")
    s = LoadScenario(scenario_text=[
        "{plant_scene: {kind: mesh_plant, mesh_plant: {file: '%s'}}}" % (tmp_path / "plant.glb")])
    parts = LoadMeshPlantParts(s.plant_scene.mesh_plant)
    assert sorted((p.kind, p.name) for p in parts) == [
        ("fruit", "fruit_a"), ("leaf", "leaf.001"), ("stem", "Stem_main")]
    f = next(p for p in parts if p.kind == "fruit")
    np.testing.assert_allclose(f.mesh.center_mass, FRUIT_C, atol=1e-4)   # back to z up
    assert f.image is not None and len(f.uv) == len(f.render.vertices) != len(f.mesh.vertices)
    model = GetPlantModel(s)                 # rendered as the file has it, textured
    vis = model.fruit_visuals[0]
    assert vis.image is not None and len(vis.uv) == len(vis.mesh.vertices)
    assert model.fruits[0].mesh_W.is_watertight


def _bad(folder, what):
    """Breaks one file of the plant in ``folder``; returns (what the message
    names: the file, or several strings, the key)."""
    key = "plant_scene.mesh_plant.folder"
    if what == "missing manifest file":
        (folder / "plant.yaml").write_text("parts:\n- {file: stems/main.obj, part: stem}\n"
                                           "- {file: fruits/nope.obj, part: fruit}\n")
        return ("plant.yaml parts[1]: ", "nope.obj: file not found"), key
    if what == "unreadable":
        (folder / "fruits" / "pepper.obj").unlink()
        (folder / "fruits" / "pepper.glb").write_bytes(b"glTF\x02\x00\x00\x00garbage")
        return "pepper.glb", key
    if what == "empty":
        (folder / "leaves" / "plain.obj").write_text("# nothing\nv 0 0 0\n")
        return "plain.obj", key
    if what == "non-finite":
        (folder / "leaves" / "plain.obj").write_text(
            "v 0 0 0.2\nv 0.05 0 nan\nv 0 0.05 0.2\nv 0.05 0.05 0.2\nf 1 2 3\nf 2 4 3\n")
        return "plain.obj", key
    if what == "no fruit":
        (folder / "fruits" / "pepper.obj").unlink()
        return str(folder), key
    if what == "leaf without area":
        V = np.array([[0, 0, 0.2], [0.05, 0, 0.2], [0.1, 0, 0.2]])
        trimesh.Trimesh(V, [[0, 1, 2]], process=False).export(folder / "leaves" / "plain.obj")
        return "plain.obj", key
    if what == "transparent card":
        for img in (folder / "leaves").glob("*.png"):
            Image.new("RGBA", (16, 16), (0, 0, 0, 0)).save(img)
        return "card.obj", key
    raise ValueError(what)


@pytest.mark.parametrize("what", ["missing manifest file", "unreadable", "empty", "non-finite",
                                  "no fruit", "leaf without area", "transparent card"])
def test_bad_file_is_one_line_naming_file_and_key(tmp_path, what):
    folder = WritePlant(tmp_path / "p")
    names, key = _bad(folder, what)
    with pytest.raises(ScenarioError) as err:
        _scenario(folder)
    msg = str(err.value)
    names = names if isinstance(names, tuple) else (names,)
    assert "\n" not in msg and all(n in msg for n in names) and msg.startswith(key + " "), msg


def test_wrong_units_suggest_the_scale(tmp_path):
    folder = WritePlant(tmp_path / "p", fruit_scale=1000.0)     # a fruit in millimetres
    with pytest.raises(ScenarioError, match=r"pepper\.obj.*scale: 0\.001"):
        _scenario(folder)
    with pytest.raises(ScenarioError, match=r"plant_scene\.mesh_plant\.targets 'x' is no fruit"):
        _scenario(WritePlant(tmp_path / "q"), targets="[x]")


def test_cli_bad_plant_exits_2_before_anything_is_written(tmp_path, capsys):
    folder = WritePlant(tmp_path / "p")
    (folder / "fruits" / "pepper.obj").write_text("v 0 0 0\n")
    out = tmp_path / "run"
    text = "{plant_scene: {kind: mesh_plant, mesh_plant: {folder: '%s'}}}" % folder
    assert main(["run", "--output", str(out), "--scenario_text", text]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "pepper.obj" in err and "Traceback" not in err
    assert not out.exists()


def test_scene_builds_in_the_station_and_renders_labels(plant):
    s = _scenario(plant, max_fem_leaves=1)
    rgb, depth, label = RenderStill(s)
    cls, inst = DecodeLabels(label)
    assert (cls == FRUIT).sum() > 50 and (cls == BRANCH).sum() > 50
    assert set(np.unique(inst[cls == LEAF])) >= {0, 1}     # the FEM card and a static leaf
    # the card hides much of the fruit: more fruit shows without the leaves
    assert UnoccludedFruitPixels(s) > 1.2 * (cls == FRUIT).sum()
    # a textured static leaf keeps its texture (the card, welded with no FEM leaf)
    s2 = _scenario(plant, max_fem_leaves=0)
    model = GetPlantModel(s2)
    k = [x.source.endswith("card.obj") for x in model.static_leaves].index(True)
    rgb2, _, label2 = RenderStill(s2)
    cls2, inst2 = DecodeLabels(label2)
    card = (cls2 == LEAF) & (inst2 == k)
    assert card.sum() > 100
    mean = rgb2[card][:, :3].astype(float).mean(0)
    assert mean[1] > 1.5 * mean[0] and mean[1] > 1.5 * mean[2], mean   # the texture's green


def test_folded_leaf_becomes_a_slab_of_its_own_triangles():
    """A leaf whose blade curls back under itself flips over its best-fit
    plane: its FEM slab is made from its own triangles, not a flat outline."""
    from lmap_drake.plants.mesh_plant import FemLeafSlab
    from lmap_drake.plants.mesh_plant_leaves import SurfaceSheet
    x = np.linspace(0, 0.06, 7)
    top = np.c_[x, np.zeros(7), np.zeros(7)]
    bend = np.c_[[0.07, 0.075, 0.07], np.zeros(3), [-0.004, -0.01, -0.016]]
    bottom = np.c_[x[::-1], np.zeros(7), np.full(7, -0.02)]
    line = np.vstack([top, bend, bottom])
    V = np.vstack([line, line + [0, 0.04, 0]])
    n = len(line)
    F = [f for k in range(n - 1) for f in ([k, k + 1, n + k], [k + 1, n + k + 1, n + k])]
    mesh = trimesh.Trimesh(V, F, process=False)
    sheet = SurfaceSheet(mesh)
    assert not sheet.flat and abs(sheet.area - mesh.area) < 1e-9
    leaf = FemLeafSlab(sheet, np.zeros(3), np.array([0, 0, 1.0]), 0.002, 500, 0)
    assert len(leaf.rest_W) == 3 * len(V) and np.all(TetVolumes(leaf.rest_W, leaf.tets) > 0)
    assert leaf.fixed.sum() >= 3 and leaf.uv[:, 0].max() > 0.07


def test_pose_places_the_files_frame(plant):
    s = _scenario(plant, X_W_plant="{translation: [0.4, 0.1, 0.0], rpy_deg: [0, 0, 90]}")
    f = GetPlantModel(s).fruits[0]
    x, y, z = FRUIT_C
    np.testing.assert_allclose(f.center_W, [0.4 - y, 0.1 + x, z], atol=1e-4)
    with pytest.raises(ScenarioError, match=r"plant_scene\.mesh_plant\.X_W_plant\.rpy_deg"):
        _scenario(plant, X_W_plant="{rpy_deg: [0, 90]}")
