"""The greenhouse plant (``plant_scene.kind: greenhouse``): deterministic by
seed, leaf and fruit counts in range, FEM only for the leaves hiding or near
the target fruits, ground truth consistent, bad keys named, its Drake model,
and the greenhouse suite file (written byte for byte, every scene builds)."""
import dataclasses as dc
import re

import numpy as np
import pytest
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
from pydrake.systems.framework import DiagramBuilder

from lmap_drake.scenario import ScenarioError
from lmap_drake.paths import DIAGRAMS_DIR
from lmap_drake.plants.config import GreenhouseFruitConfig, PlantSceneConfig
from lmap_drake.plants.greenhouse import MAX_FEM_LEAVES, GenerateGreenhousePlant
from lmap_drake.plants.greenhouse_model import GreenhouseConfigError
from lmap_drake.plants.greenhouse_scene import AddGreenhousePlant, CanopyMesh, NeighbourBases
from lmap_drake.plants.greenhouse_suite import GreenhouseSuite, RandomGreenhouseSuite
from lmap_drake.plants.multi import OCCLUDER_MIN
from lmap_drake.plants.multi_geometry import SurfaceDistance
from lmap_drake.plants.suite import WriteSuiteFile
from lmap_drake.scenario import LoadScenario
from lmap_drake.station.config import DefaultCameraConfig

P_WC = DefaultCameraConfig().X_PB.GetDeterministicValue().translation()
UR5_BASE_RADIUS = 0.075   # m, the UR5's base and shoulder (models/ur5)


def _cfg(**g):
    cfg = PlantSceneConfig(kind="greenhouse")
    for k, v in g.items():
        setattr(cfg.greenhouse, k, v)
    return cfg


@pytest.fixture(scope="module")
def two_targets():
    cfg = _cfg(seed=7, num_leaves=30, max_fem_leaves=3, fem_occluders=False, fruits=[
        GreenhouseFruitConfig(stem=0, color="red", occlusion=0.7, height=0.3),
        GreenhouseFruitConfig(stem=1, color="green", azimuth_deg=70.0, occlusion=0.5,
                              height=0.5)])
    return cfg, GenerateGreenhousePlant(cfg, P_WC)


def test_generation_is_deterministic_by_seed(two_targets):
    cfg, model = two_targets
    again = GenerateGreenhousePlant(cfg, P_WC)
    assert len(again.leaves) == len(model.leaves)
    for a, b in zip(again.AllLeafSurfaces(), model.AllLeafSurfaces()):
        np.testing.assert_array_equal(a.vertices, b.vertices)
    for a, b in zip(again.fruits, model.fruits):
        np.testing.assert_array_equal(a.mesh_W.vertices, b.mesh_W.vertices)
    other = GenerateGreenhousePlant(dc.replace(cfg, greenhouse=dc.replace(cfg.greenhouse,
                                                                           seed=8)), P_WC)
    assert not np.allclose(other.AllLeafSurfaces()[-1].vertices[:10],
                           model.AllLeafSurfaces()[-1].vertices[:10])


def test_counts_in_range(two_targets):
    cfg, model = two_targets
    g = cfg.greenhouse
    assert model.num_leaves_total == g.num_leaves
    assert len(g.fruits) <= len(model.fruits) <= len(g.fruits) + g.num_random_fruits
    assert model.targets == [0, 1]
    assert len(model.branches) == g.num_stems + len(model.fruits)   # stems, one shoot per fruit
    assert len(model.strings_W) == g.num_stems


def test_fem_leaves_are_only_those_near_the_targets(two_targets):
    cfg, model = two_targets
    g = cfg.greenhouse
    assert 1 <= len(model.leaves) <= g.max_fem_leaves
    target_occluders = {j for i in model.targets for j in model.fruits[i].occluders}
    for j, leaf in enumerate(model.leaves):
        near = min(float(SurfaceDistance([model.fruits[i].mesh_W], leaf.rest_W).min())
                   for i in model.targets)
        assert j in target_occluders or near <= g.fem_radius + 1e-9, (j, near)
    # every other leaf is static, and none of those is near a target if there was room
    assert len(model.static_leaves) == g.num_leaves - len(model.leaves)


def test_every_leaf_hiding_a_fruit_is_fem_with_fem_occluders(two_targets):
    cfg, model = two_targets
    hiding = {j for f in model.fruits for j in f.occluders}
    assert len(hiding) > cfg.greenhouse.max_fem_leaves     # the budget alone leaves some static
    assert not hiding <= set(range(len(model.leaves)))
    cfg2 = dc.replace(cfg, greenhouse=dc.replace(cfg.greenhouse, fem_occluders=True))
    model2 = GenerateGreenhousePlant(cfg2, P_WC)
    hiding2 = {j for f in model2.fruits for j in f.occluders}
    assert len(hiding2) == len(hiding) and len(hiding2) <= MAX_FEM_LEAVES
    assert hiding2 <= set(range(len(model2.leaves)))      # FEM leaves come first
    assert len(model2.leaves) == max(cfg.greenhouse.max_fem_leaves, len(hiding2))
    # the same plant: only which leaves are FEM changes
    assert sorted(len(s.vertices) for s in model2.AllLeafSurfaces()) == sorted(
        len(s.vertices) for s in model.AllLeafSurfaces())


def test_ground_truth_consistent(two_targets):
    cfg, model = two_targets
    gt = model.GroundTruthDict()
    n_fem = len(model.leaves)
    assert gt["kind"] == "greenhouse" and gt["targets"] == model.targets
    assert [lf["index"] for lf in gt["leaves"]] == list(range(cfg.greenhouse.num_leaves))
    assert [lf["fem"] for lf in gt["leaves"]] == [True] * n_fem + [False] * (
        cfg.greenhouse.num_leaves - n_fem)
    for f in gt["fruits"]:
        for j in f["occluders"]:
            assert 0 <= j < len(gt["leaves"]) and f["index"] in gt["leaves"][j]["hides_fruits"]
    for i in model.targets:
        occ = model.fruits[i].occluders
        assert occ, f"target {i} has no occluder"
        assert any(j < n_fem for j in occ), f"no occluder of target {i} is FEM: {occ}"
        # each target's occluders are FEM while there is room (round robin over the targets)
    total = {j for i in model.targets for j in model.fruits[i].occluders}
    if len(total) <= cfg.greenhouse.max_fem_leaves:
        assert all(j < n_fem for j in total)
    # an occluder does hide its fruit: taking every occluder away reveals more
    from lmap_drake.plants.multi_generator import _FruitViews
    views = _FruitViews(model.fruits, model.branches, model.p_WC)
    surfs = model.AllLeafSurfaces()
    for i in model.targets:
        assert views[i].Occlusion([surfs[j] for j in model.fruits[i].occluders[:1]]) \
            >= OCCLUDER_MIN
        rest = [s for j, s in enumerate(surfs) if j not in model.fruits[i].occluders]
        assert views[i].Occlusion(rest) < model.fruits[i].occlusion_predicted


def test_drake_model_has_one_fem_body_per_fem_leaf(two_targets):
    cfg, model = two_targets
    builder = DiagramBuilder()
    plant, sg = AddMultibodyPlant(MultibodyPlantConfig(time_step=0.01), builder)
    handles = AddGreenhousePlant(plant, sg, model, cfg)
    plant.Finalize()
    assert plant.deformable_model().num_bodies() == len(model.leaves)
    assert len(handles["fruit_geometry_ids"]) == len(model.fruits)


@pytest.mark.parametrize("key,value,name", [
    ("num_leaves", 14, "plant_scene.greenhouse.num_leaves"),
    ("num_leaves", 61, "plant_scene.greenhouse.num_leaves"),
    ("num_stems", 4, "plant_scene.greenhouse.num_stems"),
    ("leaf_length", [0.1, 0.05], "plant_scene.greenhouse.leaf_length"),
    ("max_fem_leaves", 9, "plant_scene.greenhouse.max_fem_leaves"),
])
def test_bad_values_name_the_key(key, value, name):
    with pytest.raises(GreenhouseConfigError) as err:
        GenerateGreenhousePlant(_cfg(**{key: value}), P_WC)
    assert err.value.key == name
    with pytest.raises(ScenarioError, match=re.escape(name)):
        LoadScenario(scenario_text="{plant_scene: {kind: greenhouse, greenhouse: {%s: %s}}}"
                     % (key, value))


def test_bad_fruit_values_name_the_key():
    with pytest.raises(ScenarioError, match=r"plant_scene\.greenhouse\.fruits\[0\]\.color"):
        LoadScenario(scenario_text="{plant_scene: {kind: greenhouse, greenhouse: "
                                   "{fruits: [{color: purple}]}}}")
    with pytest.raises(ScenarioError, match=r"plant_scene\.greenhouse\.fruits\[0\]\.stem"):
        LoadScenario(scenario_text="{plant_scene: {kind: greenhouse, greenhouse: "
                                   "{num_stems: 1, fruits: [{stem: 1}]}}}")


def test_suite_file_is_written_byte_for_byte(tmp_path):
    n, path = WriteSuiteFile(tmp_path / "g.yaml", greenhouse=True)
    assert n == len(GreenhouseSuite()) >= 12
    assert path.read_text() == (DIAGRAMS_DIR / "greenhouse_suite.yaml").read_text()


def test_every_suite_scene_loads_and_builds():
    """Every scene of the committed suite loads and its plant model builds
    (generation only, no episode); each target has an FEM occluder."""
    from lmap_drake.plants.plant_station import GetPlantModel
    text = (DIAGRAMS_DIR / "greenhouse_suite.yaml").read_text()
    names = re.findall(r"^(\w+):$", text, re.M)
    assert len(names) >= 12
    kinds = set()
    for name in names:
        s = LoadScenario(filename=DIAGRAMS_DIR / "greenhouse_suite.yaml", scenario_name=name)
        assert s.plant_scene.kind == "greenhouse" and len(s.lights) == 3
        model = GetPlantModel(s)
        assert 15 <= model.num_leaves_total <= 60
        for i in model.targets:
            f = model.fruits[i]
            if s.plant_scene.greenhouse.fruits[i].cover_leaves:
                assert any(j < len(model.leaves) for j in f.occluders), (name, i)
            kinds.add(len([j for j in f.occluders if j < len(model.leaves)]) >= 2)
        # the arm's base (radius UR5_BASE_RADIUS) stands clear of every
        # plant of the row, each as wide as this one (its copies)
        base = np.asarray(s.plant_scene.p_W_branch_base, float)
        leaves, _ = CanopyMesh(model)
        reach = np.linalg.norm((leaves.vertices - base)[:, :2], axis=1).max()
        p_WB = s.robot.X_WB.GetDeterministicValue().translation()
        for q in np.vstack([base, NeighbourBases(base, model.p_WC)]):
            gap = np.linalg.norm((p_WB - q)[:2]) - UR5_BASE_RADIUS - reach
            assert gap > 0.0, (name, q, gap)
    assert kinds == {True, False}     # some targets under two FEM leaves, some under one


def test_suite_scenes_draw_their_own_exposure_and_white_balance():
    """The committed suite's scenes keep the default L515 camera model but
    each its own noise seed, so the per-scene colour change (exposure gain,
    white balance) differs between scenes."""
    from lmap_drake.station.camera_noise import CameraProfile, NoisyColor
    text = (DIAGRAMS_DIR / "greenhouse_suite.yaml").read_text()
    gains = set()
    for name in re.findall(r"^(\w+):$", text, re.M):
        s = LoadScenario(filename=DIAGRAMS_DIR / "greenhouse_suite.yaml", scenario_name=name)
        cam = s.camera_noise
        assert cam.enabled and CameraProfile(cam) == "l515" and cam.exposure_variation > 0
        grey = np.full((4, 4, 3), 128, np.uint8)
        quiet = dc.replace(cam, read_noise=0.0, shot_noise=0.0, illumination_gradient=0.0)
        seed = s.random_seed + cam.seed_offset + 7919 * 0        # as the station seeds camera0
        gains.add(tuple(NoisyColor(grey, quiet, seed, 0)[0, 0]))
    assert len(gains) == len(re.findall(r"^(\w+):$", text, re.M))


def test_random_suite_is_deterministic():
    a = RandomGreenhouseSuite(1, 3)
    b = RandomGreenhouseSuite(1, 3)
    assert list(a) == ["gh_random_3_000"]
    assert a["gh_random_3_000"] == b["gh_random_3_000"]
    assert 15 <= a["gh_random_3_000"].greenhouse.num_leaves <= 60


def test_a_plant_with_more_than_eight_leaves_hiding_fruits_gets_them_all_as_fem():
    """A dense random plant (``make_suite.py --greenhouse --random 8 --seed
    6464``, its fourth: 11 leaves hide a fruit): every one is FEM, so a
    planner grasping any true occluder grasps a leaf that moves (at 8 FEM
    leaves, 3 of those 8 plants ended at a grasp on a static occluder)."""
    from lmap_drake.plants.greenhouse_suite import RandomGreenhouseSuite
    cfg = RandomGreenhouseSuite(8, 6464)["gh_random_6464_003"]
    model = GenerateGreenhousePlant(cfg, P_WC)
    hiding = {j for f in model.fruits for j in f.occluders}
    assert len(hiding) > 8
    assert hiding <= set(range(len(model.leaves)))        # FEM leaves come first


def test_leaves_hiding_a_sliver_of_a_fruit_are_fem_after_the_occluders():
    """A leaf hiding less than ``OCCLUDER_MIN`` of a fruit may still be
    grasped (the planner's fruit shapes are larger than the true ones): with
    ``fem_occluders`` it is FEM, after every occluder; without, only the
    budget's occluders are."""
    import trimesh
    from types import SimpleNamespace
    from lmap_drake.plants.greenhouse import _ChooseFem
    fruit = SimpleNamespace(mesh_W=trimesh.creation.icosphere(radius=0.03))
    far = [SimpleNamespace(vertices=np.array([[1.0 + j, 0.0, 0.0]])) for j in range(6)]
    occluders, partial = [[3, 1], [4]], [[0], [5, 3]]
    g = SimpleNamespace(max_fem_leaves=2, fem_radius=0.06, fem_occluders=True)
    chosen = _ChooseFem(g, [0], occluders, [fruit, fruit], far, set(), partial)
    assert chosen == [3, 1, 4, 0, 5]       # occluders (targets first), then the slivers
    g.fem_occluders = False
    assert _ChooseFem(g, [0], occluders, [fruit, fruit], far, set(), partial) == [3, 1]
