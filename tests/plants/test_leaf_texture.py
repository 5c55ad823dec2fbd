"""Greenhouse leaf textures (``plants/leaf_texture.py``, ``greenhouse.textures``):
deterministic atlases with the features they claim (lighter veins, a base
to tip gradient, mottling, a darker and greyer lower side), OBJ texture
coordinates on the right half per side, embedded FEM render meshes inside
their tetrahedra, and a rendered greenhouse view whose leaves (FEM and
static) are no longer flat while the label image stays the same."""
import numpy as np
import pytest
from PIL import Image
from pydrake.geometry import (ClippingRange, ColorRenderCamera, DepthRange, DepthRenderCamera,
                              MakeRenderEngineVtk, RenderCameraCore, RenderEngineVtkParams,
                              SceneGraph)
from pydrake.math import RigidTransform
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.sensors import CameraInfo, RgbdSensor
from scipy import ndimage

from lmap_drake.labels import LEAF, DecodeLabels
from lmap_drake.plants.config import PlantSceneConfig
from lmap_drake.plants.greenhouse import GenerateGreenhousePlant
from lmap_drake.plants.greenhouse_model import GreenhouseConfigError, ValidateGreenhouseConfig
from lmap_drake.plants.greenhouse_scene import AddGreenhousePlant
from lmap_drake.plants.leaf import BoundaryTriangles
from lmap_drake.plants.leaf_texture import (FRUIT_TEX, LUMA, FruitObjText, FruitTexture,
                                            InsideTets, LeafObjText, LeafTexture,
                                            LeafTextureFiles)
from lmap_drake.station.config import DefaultCameraConfig

GREEN = (0.16, 0.42, 0.10)


def _tex(index=0, seed=5):
    return LeafTexture(seed, index, GREEN, (-0.03, 0.12), 0.04, 0.12)


def test_texture_is_deterministic_in_seed_and_index():
    a, b = _tex(), _tex()
    assert np.array_equal(a.rgb, b.rgb)
    assert not np.array_equal(a.rgb, _tex(index=1).rgb)
    assert not np.array_equal(a.rgb, _tex(seed=6).rgb)


def test_texture_has_lighter_veins_a_gradient_mottling_and_a_darker_greyer_lower_side():
    t = _tex()
    lum = t.rgb.astype(float) @ LUMA
    sat = t.rgb.max(axis=2).astype(float) - t.rgb.min(axis=2)
    blade = (t.u > 0.01) & (t.u < 0.11)
    up = np.zeros(lum.shape, bool)
    up[t.upper] = True
    vein, between = blade & (t.vein > 0.6), blade & (t.vein < 0.05)
    for side in (up, ~up):
        assert lum[vein & side].mean() > lum[between & side].mean() + 8     # veins lighter
    base, tip = between & up & (t.u < 0.04), between & up & (t.u > 0.08)
    assert lum[base].mean() > lum[tip].mean() + 5                           # base -> tip
    # mottling: within one column (one u) of inter-vein blade the brightness varies
    cols = [lum[:, k][between[:, k] & up[:, k]] for k in range(lum.shape[1])]
    assert np.median([c.std() for c in cols if len(c) > 10]) > 1.5
    # lower side: darker and greyer than the upper side
    assert lum[between & ~up].mean() < 0.9 * lum[between & up].mean()
    assert sat[between & ~up].mean() < 0.8 * sat[between & up].mean()


def test_fruit_texture_has_darker_shoulders_streaks_and_a_gloss_band():
    red = (0.72, 0.04, 0.04)
    t = FruitTexture(2, 1, red)
    assert np.array_equal(t, FruitTexture(2, 1, red)) and not np.array_equal(t, FruitTexture(2, 0, red))
    lum = t.astype(float) @ LUMA
    n = FRUIT_TEX
    col = lum[n // 4: 3 * n // 4].mean(axis=0)             # across the fruit, mid-height
    assert col.max() > 1.5 * np.median(col)                 # the gloss band
    assert lum[: n // 10].mean() < 0.9 * lum[n // 3: n // 2].mean()   # shoulders (top rows)
    far = np.argsort(col)[: n // 3]                         # away from the band
    assert lum[n // 3: n // 2][:, far].std(axis=1).mean() > 1.0       # streaks across


def test_fruit_obj_maps_its_axis_to_v():
    import trimesh
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.04)
    X = np.eye(4)
    X[:3, 3] = [0.5, 0.0, 0.3]
    text = FruitObjText(mesh, X)
    vt = np.array([[float(x) for x in ln.split()[1:]] for ln in text.splitlines()
                   if ln.startswith("vt ")])
    top = np.argmax(mesh.vertices[:, 2])
    assert vt.min() >= 0 and vt.max() <= 1 and vt[top, 1] == pytest.approx(1.0)


def _leaf():
    cfg = PlantSceneConfig(kind="greenhouse")
    model = GenerateGreenhousePlant(cfg, DefaultCameraConfig().X_PB.GetDeterministicValue()
                                    .translation())
    return model, model.leaves[0]


def test_obj_puts_each_side_on_its_half_and_files_are_reused(tmp_path):
    model, leaf = _leaf()
    surf = leaf.Surface()
    text = LeafObjText(surf.vertices, surf.faces, leaf.uv, leaf.normal_W)
    vt = np.array([[float(x) for x in ln.split()[1:]] for ln in text.splitlines()
                   if ln.startswith("vt ")])
    faces = [ln.split()[1:] for ln in text.splitlines() if ln.startswith("f ")]
    assert len(faces) == len(surf.faces) and vt.min() >= 0 and vt.max() <= 1
    fn = surf.face_normals @ leaf.normal_W >= 0
    t_of = np.array([[vt[int(c.split("/")[1]) - 1, 1] for c in f] for f in faces])
    assert (t_of[fn] > 0.5).all() and (t_of[~fn] < 0.5).all()
    a = LeafTextureFiles(1, 0, GREEN, surf.vertices, surf.faces, leaf.uv, leaf.normal_W)
    b = LeafTextureFiles(1, 0, GREEN, surf.vertices, surf.faces, leaf.uv, leaf.normal_W)
    assert a == b
    rgb = np.asarray(Image.open(a[1]).convert("RGB"))
    (u0, u1) = leaf.uv[:, 0].min(), leaf.uv[:, 0].max()
    expect = LeafTexture(1, 0, GREEN, (u0, u1), np.abs(leaf.uv[:, 1]).max(), u1).rgb
    assert np.array_equal(rgb, expect)


def test_embedded_vertices_lie_inside_their_tetrahedra():
    _, leaf = _leaf()
    V = InsideTets(leaf.rest_W, leaf.tets)
    used = np.unique(leaf.tets)
    assert np.abs(V - leaf.rest_W).max() < 1e-5          # microns
    owner = np.full(len(V), -1)
    owner[leaf.tets.ravel()] = np.repeat(np.arange(len(leaf.tets)), 4)
    for i in used[:: max(1, len(used) // 200)]:
        P = leaf.rest_W[leaf.tets[owner[i]]]
        lam = np.linalg.solve(np.c_[P[1:] - P[0]].T, V[i] - P[0])
        assert lam.min() > 0 and lam.sum() < 1
    assert set(np.unique(BoundaryTriangles(leaf.tets))) <= set(used)


def test_textures_key_must_be_a_bool():
    cfg = PlantSceneConfig(kind="greenhouse")
    cfg.greenhouse.textures = "yes"
    with pytest.raises(GreenhouseConfigError, match="plant_scene.greenhouse.textures"):
        ValidateGreenhouseConfig(cfg)


def _render(textures: bool):
    """camera0's colour and label image of a small greenhouse plant."""
    cam = DefaultCameraConfig()
    X_WC = cam.X_PB.GetDeterministicValue()
    cfg = PlantSceneConfig(kind="greenhouse")
    g = cfg.greenhouse
    g.seed, g.num_leaves, g.num_stems, g.max_fem_leaves = 3, 20, 1, 2
    g.num_random_fruits, g.dressing, g.textures = 0, False, textures
    model = GenerateGreenhousePlant(cfg, X_WC.translation())
    builder = DiagramBuilder()
    plant, sg = AddMultibodyPlant(MultibodyPlantConfig(time_step=0.01), builder)
    sg.AddRenderer("vtk", MakeRenderEngineVtk(RenderEngineVtkParams()))
    AddGreenhousePlant(plant, sg, model, cfg)
    plant.Finalize()
    core = RenderCameraCore("vtk", CameraInfo(cam.width, cam.height, cam.focal_x(),
                                              cam.focal_y(), *cam.principal_point()),
                            ClippingRange(0.05, 5.0), RigidTransform())
    sensor = builder.AddSystem(RgbdSensor(SceneGraph.world_frame_id(), X_WC,
                                          ColorRenderCamera(core),
                                          DepthRenderCamera(core, DepthRange(0.05, 5.0))))
    builder.Connect(sg.get_query_output_port(), sensor.query_object_input_port())
    diagram = builder.Build()
    ctx = sensor.GetMyContextFromRoot(diagram.CreateDefaultContext())
    rgb = np.array(sensor.color_image_output_port().Eval(ctx).data[..., :3], float)
    label = np.array(sensor.label_image_output_port().Eval(ctx).data[..., 0])
    return rgb, label, len(model.leaves)


def _detail(lum, mask):
    """Std of the brightness minus its local (1.5 px, within ``mask``) mean
    over ``mask`` eroded by 2 px: the fine detail of a surface, not its
    shading."""
    m = mask.astype(float)
    mean = ndimage.gaussian_filter(lum * m, 1.5) / np.maximum(ndimage.gaussian_filter(m, 1.5),
                                                               1e-6)
    core = ndimage.binary_erosion(mask, iterations=2)
    return float((lum - mean)[core].std()), int(core.sum())


def test_rendered_leaves_are_textured_and_labels_unchanged():
    rgb0, lab0, K = _render(False)
    rgb1, lab1, _ = _render(True)
    assert np.array_equal(lab0, lab1)
    cls, inst = DecodeLabels(lab0)
    lum0, lum1 = rgb0 @ LUMA, rgb1 @ LUMA
    checked = []
    for j in np.unique(inst[cls == LEAF]):
        m = (cls == LEAF) & (inst == j)
        flat, n = _detail(lum0, m)
        if n < 1000 or flat > 1.5:       # a large leaf facing the camera, flat without texture
            continue
        textured, _ = _detail(lum1, m)
        assert textured > 2.5 and textured > 3 * flat, (j, flat, textured)
        assert lum1[ndimage.binary_erosion(m, iterations=2)].std() > 5.0
        checked.append(int(j) < K)
    assert True in checked and False in checked      # an FEM and a static leaf
