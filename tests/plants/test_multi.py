"""The multi-fruit plant generator (``plant_scene.kind: multi``), without a
Diagram: determinism, counts, per-fruit occlusion, leaves apart at rest,
ground truth and config errors naming the key."""
import json

import numpy as np
import pytest

from lmap_drake.plants.config import MultiFruitConfig, PlantSceneConfig
from lmap_drake.plants.generator import (OCCLUSION_TOLERANCE, MeshSignedDistance,
                                         PlantGenerationError)
from lmap_drake.plants.multi import MultiConfigError, SaveMultiGroundTruth
from lmap_drake.plants.multi_generator import GenerateMultiPlant
from lmap_drake.plants.multi_geometry import BranchClearance, FruitView, LeafLeafGap
from lmap_drake.scenario import LoadScenario, ScenarioError

P_WC = np.array([0.5, -0.6, 0.47])


@pytest.fixture(scope="module")
def default_plant():
    return GenerateMultiPlant(PlantSceneConfig(kind="multi"), P_WC)


def _cfg(fruits=None, **multi):
    cfg = PlantSceneConfig(kind="multi")
    if fruits is not None:
        cfg.multi.fruits = fruits
    for k, v in multi.items():
        setattr(cfg.multi, k, v)
    return cfg


def test_counts_and_structure(default_plant):
    m = default_plant
    cfg = PlantSceneConfig(kind="multi").multi
    assert len(m.fruits) == len(cfg.fruits) == 3
    assert len(m.leaves) == cfg.num_leaves == 4
    assert len(m.branches) == 1 + len(m.fruits)          # stem + one shoot per fruit
    for i, (f, fc) in enumerate(zip(m.fruits, cfg.fruits)):
        assert f.shoot == i + 1
        assert sum(lf.fruit == i for lf in m.leaves) == fc.num_leaves
        assert f.mesh_W.is_watertight and f.volume > 1e-4
        np.testing.assert_allclose(f.X_WO[:3, 3], f.center_W)
        # The stalk ends on the fruit's shoot.
        assert BranchClearance(f.stalk_W[1:], m.branches[f.shoot]).min() < 0
    for lf in m.leaves:
        assert 500 <= len(lf.tets) <= 1500                  # like the single plant's leaf
        assert lf.fixed.sum() >= 6
        # The petiole base sits on its own shoot (or the stem).
        assert BranchClearance(lf.rest_W[lf.fixed], m.branches[lf.shoot]).min() < 0.005


def test_deterministic(default_plant):
    b = GenerateMultiPlant(PlantSceneConfig(kind="multi"), P_WC)
    for la, lb in zip(default_plant.leaves, b.leaves):
        np.testing.assert_array_equal(la.rest_W, lb.rest_W)
    for fa, fb in zip(default_plant.fruits, b.fruits):
        np.testing.assert_array_equal(fa.mesh_W.vertices, fb.mesh_W.vertices)
    assert default_plant.GroundTruthDict() == b.GroundTruthDict()


def test_per_fruit_occlusion_and_occluders(default_plant):
    m = default_plant
    cfg = PlantSceneConfig(kind="multi").multi
    for i, (f, fc) in enumerate(zip(m.fruits, cfg.fruits)):
        own = [j for j, lf in enumerate(m.leaves) if lf.fruit == i]
        if fc.num_leaves:
            assert f.occlusion_predicted == pytest.approx(fc.occlusion, abs=OCCLUSION_TOLERANCE)
            assert set(own) <= set(f.occluders)
    # Independent check of one fruit: a fresh ray cast with every leaf.
    others = [g.mesh_W for k, g in enumerate(m.fruits) if k != 0]
    view = FruitView(m.fruits[0].mesh_W, others, P_WC, n=2000)
    occ = view.Occlusion([lf.Surface() for lf in m.leaves])
    assert occ == pytest.approx(m.fruits[0].occlusion_predicted, abs=0.04)


def test_two_leaves_over_one_fruit_and_leaves_apart_at_rest(default_plant):
    m = default_plant
    assert any(sum(lf.fruit == i for lf in m.leaves) == 2 for i in range(len(m.fruits)))
    gap = PlantSceneConfig().multi.leaf_gap
    surfs = [lf.Surface() for lf in m.leaves]
    for a in range(len(surfs)):
        for b in range(a + 1, len(surfs)):
            assert LeafLeafGap(surfs[a], surfs[b]) >= gap - 1e-4
        for f in m.fruits:
            assert MeshSignedDistance(f.mesh_W, m.leaves[a].rest_W).min() > 0.003


def test_one_leaf_ceiling_is_what_the_fruit_shows_with_its_best_leaf_taken_away(default_plant):
    """The default plant's two-leaf fruit cannot be shown >= 0.9 by moving
    one leaf (its ceiling is checked by a fresh ray cast without each
    leaf); a one-leaf fruit's ceiling is about 1."""
    m = default_plant
    surfs = [lf.Surface() for lf in m.leaves]
    two = [i for i in range(len(m.fruits)) if sum(lf.fruit == i for lf in m.leaves) == 2]
    for i, f in enumerate(m.fruits):
        others = [g.mesh_W for k, g in enumerate(m.fruits) if k != i]
        view = FruitView(f.mesh_W, others, P_WC, n=2000)
        best = max([1 - view.Occlusion([s for k, s in enumerate(surfs) if k != j])
                    for j in f.occluders] or [1 - view.Occlusion(surfs)])
        assert f.one_leaf_ceiling == pytest.approx(best, abs=0.05)
        assert f.one_leaf_ceiling >= 1 - f.occlusion_predicted - 1e-9
        if i in two:
            assert f.one_leaf_ceiling < 0.9
        elif len(f.occluders) == 1:
            assert f.one_leaf_ceiling > 0.95


def test_ground_truth_file(default_plant, tmp_path):
    names = SaveMultiGroundTruth(default_plant, tmp_path)
    gt = json.loads((tmp_path / "ground_truth.json").read_text())
    assert len(gt["fruits"]) == 3 and len(gt["leaves"]) == 4
    assert gt["fruits"][0]["occluders"] == default_plant.fruits[0].occluders
    assert gt["fruits"][0]["one_leaf_ceiling"] == default_plant.fruits[0].one_leaf_ceiling
    assert {"fruit_center_W", "X_WO", "occlusion_predicted", "shoot"} <= set(gt["fruits"][0])
    assert all((tmp_path / n).exists() for n in names)


def test_two_fruits_with_more_free_leaves():
    f = [MultiFruitConfig(height=0.16, side=1.0, occlusion=0.5, num_leaves=1),
         MultiFruitConfig(height=0.28, side=-1.0, occlusion=0.7, num_leaves=1)]
    m = GenerateMultiPlant(_cfg(f, num_leaves=4), P_WC)
    assert len(m.fruits) == 2 and len(m.leaves) == 4
    assert sum(lf.fruit == -1 for lf in m.leaves) == 2
    for fr, fc in zip(m.fruits, f):
        assert fr.occlusion_predicted == pytest.approx(fc.occlusion, abs=OCCLUSION_TOLERANCE)


@pytest.mark.parametrize("text, key", [
    ("{multi: {num_leaves: 7}}", "plant_scene.multi.num_leaves"),
    ("{multi: {num_leaves: 2}}", "plant_scene.multi.num_leaves"),   # fewer than the fruits'
    ("{multi: {fruits: [{height: 0.2}]}}", "plant_scene.multi.fruits"),
    ("{multi: {fruits: [{height: 0.2}, {height: 0.9}]}}", "plant_scene.multi.fruits[1].height"),
    ("{multi: {fruits: [{num_leaves: 3}, {height: 0.4}]}}",
     "plant_scene.multi.fruits[0].num_leaves"),
    ("{multi: {fruits: [{occlusion: 1.2}, {height: 0.4}]}}",
     "plant_scene.multi.fruits[0].occlusion"),
    ("{multi: {fruits: [{side: 0}, {height: 0.4}]}}", "plant_scene.multi.fruits[0].side"),
    ("{multi: {fruits: [{fruit: {size: [0.07, 0.07]}}, {height: 0.4}]}}",
     "plant_scene.multi.fruits[0].fruit.size"),
    ("{multi: {leaf_gap: -0.001}}", "plant_scene.multi.leaf_gap"),
    ("{multi: {fruits: [{height: .nan}, {height: 0.4}]}}", "plant_scene.multi.fruits[0].height"),
])
def test_bad_config_names_the_key(text, key):
    with pytest.raises(ScenarioError) as err:
        LoadScenario(scenario_text=f"{{plant_scene: {{kind: multi, {text[1:-1]}}}}}")
    assert str(err.value).startswith(key + " ")


def test_unknown_key_in_a_fruit_is_named():
    with pytest.raises(ScenarioError) as err:
        LoadScenario(scenario_text="{plant_scene: {kind: multi, multi: {fruits: "
                                   "[{height: 0.2}, {fruit: {colr: 1}}]}}}")
    assert "unknown key(s) plant_scene.multi.fruits[1].fruit.colr in --scenario_text" \
        in str(err.value)


def test_unbuildable_plant_names_the_key():
    # Two fruits on the same side at almost the same height overlap.
    f = [MultiFruitConfig(height=0.2, side=1.0, num_leaves=1),
         MultiFruitConfig(height=0.23, side=1.0, num_leaves=1)]
    with pytest.raises(MultiConfigError) as err:
        GenerateMultiPlant(_cfg(f, num_leaves=2), P_WC)
    assert err.value.key == "plant_scene.multi.fruits[1].height"
    assert isinstance(err.value, PlantGenerationError)


def test_multi_suite_file_is_the_multi_suite():
    """diagrams/multi_suite.yaml loads and holds MultiSuite() (regenerate it
    with scripts/make_suite.py --multi); building every scene is left to
    scripts/render_multi_suite.py (about 5 s each)."""
    from pydrake.common.yaml import yaml_dump_typed

    from lmap_drake.paths import DIAGRAMS_DIR
    from lmap_drake.plants.suite import MultiSuite
    from lmap_drake.studies.shape_benchmark import SuiteScenarioNames
    path = DIAGRAMS_DIR / "multi_suite.yaml"
    names = SuiteScenarioNames(path)
    suite = MultiSuite()
    assert names == list(suite) and len(names) >= 6
    two = 0
    for name in names:
        ps = LoadScenario(filename=path, scenario_name=name).plant_scene
        assert ps.kind == "multi" and 2 <= len(ps.multi.fruits) <= 4
        assert yaml_dump_typed(ps, schema=PlantSceneConfig) == \
            yaml_dump_typed(suite[name], schema=PlantSceneConfig)
        two += any(f.num_leaves == 2 for f in ps.multi.fruits)
        # every scene reveals every fruit, with the arm in the aisle
        s = LoadScenario(filename=path, scenario_name=name)
        assert s.planner.targets == "all"
        assert np.allclose(s.robot.X_WB.GetDeterministicValue().translation(), [0.1, -0.25, 0])
    assert two >= 2


def test_random_multi_plants_are_buildable_varied_and_fixed_by_their_seed(tmp_path):
    """``make_suite.py --multi --random``: plants of 2-4 fruits and at most 6
    leaves that the generator builds as drawn, the same for one seed."""
    from lmap_drake.plants.suite import RandomMultiSuite, SuiteYaml, MULTI_SCENE_EXTRA
    a, b = RandomMultiSuite(1, seed=11), RandomMultiSuite(1, seed=11)
    c = RandomMultiSuite(1, seed=12)
    sizes = lambda s: [[f.fruit.size for f in x.multi.fruits] for x in s.values()]
    assert sizes(a) == sizes(b) and sizes(a) != sizes(c)
    for cfg in a.values():
        assert 2 <= len(cfg.multi.fruits) <= 4 and cfg.multi.num_leaves <= 6
        model = GenerateMultiPlant(cfg, P_WC)
        assert len(model.fruits) == len(cfg.multi.fruits)
        for f, m in zip(cfg.multi.fruits, model.fruits):
            if f.num_leaves and f.occlusion > 0:    # hidden as drawn
                assert abs(m.occlusion_predicted - f.occlusion) <= OCCLUSION_TOLERANCE + 1e-9
    path = tmp_path / "random_multi.yaml"
    path.write_text(SuiteYaml(a, "# test", MULTI_SCENE_EXTRA))
    for name in a:
        s = LoadScenario(filename=path, scenario_name=name)
        assert s.plant_scene.kind == "multi" and s.planner.targets == "all"
        assert sizes({name: s.plant_scene}) == sizes({name: a[name]})


def test_make_suite_refuses_a_negative_seed_in_one_line(tmp_path):
    import subprocess
    import sys
    from lmap_drake.paths import REPO_ROOT
    out = tmp_path / "s.yaml"
    r = subprocess.run([sys.executable, str(REPO_ROOT / "scripts" / "make_suite.py"), "--multi",
                        "--random", "2", "--seed", "-1", "--out", str(out)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "--seed and --random must be >= 0" in r.stderr
    assert "Traceback" not in r.stderr and not out.exists()


def _file_pepper(folder, scale=1.0):
    """An egg-shaped test fruit (3.4 x 3.4 x 4.4 cm, OBJ) and a straight
    stalk mesh on its top (STL), in the file convention (+z = peduncle
    axis), times ``scale``."""
    import trimesh
    fruit = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    fruit.apply_scale([0.017, 0.017, 0.022])
    stalk = trimesh.creation.cylinder(radius=0.003, segment=[[0, 0, 0.020], [0.01, 0, 0.05]])
    for m in (fruit, stalk):
        m.apply_scale(scale)
    fruit.export(folder / "egg.obj")
    stalk.export(folder / "egg.peduncle.stl")
    return folder / "egg.obj", folder / "egg.peduncle.stl", fruit.volume / scale ** 3


def test_a_fruit_mesh_from_a_file_on_a_multi_plant(tmp_path):
    """``multi.fruits[i].fruit.mesh_file`` places the file's pepper (and its
    stalk, ``peduncle_file``) on its shoot like a procedural one: the same
    volume, the stalk from the file stalk's far end to the shoot, the
    requested occlusion, the file named in the ground truth; the other
    fruits stay procedural."""
    f, ped, volume = _file_pepper(tmp_path)
    s = LoadScenario(scenario_text=(
        "{plant_scene: {kind: multi, multi: {num_leaves: 2, fruits: [{height: 0.2}, "
        "{height: 0.42, side: -1, occlusion: 0.6, fruit: {mesh_file: '%s', peduncle_file: '%s'}}"
        "]}}}" % (f, ped)))
    m = GenerateMultiPlant(s.plant_scene, P_WC)
    procedural, egg = m.fruits
    assert egg.volume == pytest.approx(volume, rel=1e-6)
    assert egg.mesh_W.is_watertight and egg.peduncle_mesh_W is not None
    # the file stalk's far end is where the straight stalk to the shoot starts
    assert np.abs(egg.peduncle_mesh_W.vertices - egg.stalk_W[0]).sum(1).min() < 1e-9
    assert BranchClearance(egg.stalk_W[1:], m.branches[egg.shoot]).min() < 0
    assert egg.occlusion_predicted == pytest.approx(0.6, abs=OCCLUSION_TOLERANCE)
    gt = m.GroundTruthDict()["fruits"]
    assert gt[1]["fruit_source"] == str(f) and gt[0]["fruit_source"] == "procedural"
    assert procedural.peduncle_mesh_W is None


@pytest.mark.parametrize("fruit, key, words", [
    ("{mesh_file: /nope/egg.obj}", "plant_scene.multi.fruits[1].fruit.mesh_file", "not found"),
    ("{mesh_file: MM}", "plant_scene.multi.fruits[1].fruit.mesh_file",
     "set plant_scene.multi.fruits[1].fruit.mesh_scale: 0.001"),
    ("{peduncle_file: PED}", "plant_scene.multi.fruits[1].fruit.peduncle_file",
     "needs plant_scene.multi.fruits[1].fruit.mesh_file"),
])
def test_a_bad_fruit_file_on_a_multi_plant_names_the_fruit(tmp_path, fruit, key, words):
    """Checked when the scenario loads, before anything is built; the
    message names that fruit's key and the file."""
    mm = tmp_path / "mm"
    mm.mkdir()
    f_mm, ped_mm, _ = _file_pepper(mm, scale=1000.0)
    fruit = fruit.replace("MM", str(f_mm)).replace("PED", str(ped_mm))
    with pytest.raises(ScenarioError) as err:
        LoadScenario(scenario_text="{plant_scene: {kind: multi, multi: {fruits: [{height: 0.2}, "
                                   "{height: 0.42, side: -1, fruit: %s}]}}}" % fruit)
    msg = str(err.value)
    assert msg.startswith(key + " ") and words in msg, msg
