"""The randomisation ablation's switches (``studies/segnet_ablation.py``,
``studies/segnet_greenhouse.py``): a group switched off leaves the same plant
with only that group plain; bad options are refused before any render."""
import numpy as np
import pytest

from lmap_drake.errors import InputError
from lmap_drake.perception.training import RandomCrop
from lmap_drake.studies.segnet_ablation import AblationOptions, AblationTable, CheckOptions
from lmap_drake.studies.segnet_greenhouse import RandomGreenhouseRenderScenario

SEED = 90001


def test_switching_a_group_off_keeps_the_plant_and_plains_only_that_group():
    s, kind, _ = RandomGreenhouseRenderScenario(SEED)
    g = s.plant_scene.greenhouse
    for off, check in [
            ("textures", lambda t: not t.plant_scene.greenhouse.textures
             and t.plant_scene.greenhouse.leaf_color_variation == 0.05),
            ("clutter", lambda t: not t.plant_scene.greenhouse.dressing
             and not t.plant_scene.greenhouse.neighbour_row),
            ("photometric", lambda t: t.camera_noise.exposure_variation == 0.0
             and t.camera_noise.white_balance_variation == 0.0),
            ("lights", lambda t: len(t.lights) != len(s.lights)
             or any(a.frame != b.frame for a, b in zip(t.lights, s.lights))),
            ("camera_pose", lambda t: not np.allclose(
                t.cameras["camera0"].X_PB.GetDeterministicValue().translation(),
                s.cameras["camera0"].X_PB.GetDeterministicValue().translation()))]:
        t, kind_t, _ = RandomGreenhouseRenderScenario(SEED, (off,))
        assert check(t), off
        h = t.plant_scene.greenhouse
        assert (h.num_stems, h.num_leaves, h.seed, kind_t) == (g.num_stems, g.num_leaves,
                                                                g.seed, kind), off
        assert t.robot.initial_q == s.robot.initial_q, off
        assert t.camera_noise.seed_offset == s.camera_noise.seed_offset, off
    assert g.textures or g.dressing or s.camera_noise.exposure_variation > 0


def test_unknown_group_is_refused():
    with pytest.raises(ValueError, match="unknown randomisation"):
        RandomGreenhouseRenderScenario(SEED, ("texture",))


def test_crop_without_jitter_keeps_the_colours():
    rng = np.random.default_rng(0)
    x = rng.uniform(-0.5, 0.5, (8, 64, 64)).astype(np.float16)
    y = np.full((64, 64), 2, np.int64)
    sample = {"x": x, "y": y}
    xc, _, _ = RandomCrop(sample, np.random.default_rng(1), size=64, jitter=False)
    xj, _, _ = RandomCrop(sample, np.random.default_rng(1), size=64, jitter=True)
    plain = x[:3].astype(np.float32)
    assert np.allclose(xc[:3], plain) or np.allclose(xc[:3], plain[:, :, ::-1])
    assert not np.allclose(xj[:3], xc[:3])


@pytest.mark.parametrize("kw, flag", [({"variants": ("all", "no_texture")}, "--variants"),
                                      ({"variants": ("no_lights",)}, "'all'"),
                                      ({"steps": 0}, "--steps"),
                                      ({"init": "nope.pt"}, "--init")])
def test_bad_options_are_refused_before_anything_runs(kw, flag, tmp_path):
    with pytest.raises(InputError, match=flag.replace("-", r"\-")):
        CheckOptions(AblationOptions(out=str(tmp_path / "o"), **kw))
    assert not (tmp_path / "o").exists()


def test_table_shows_each_variant_and_its_difference():
    row = {"fruit_iou": 0.8, "leaf_iou": 0.9, "branch_iou": 0.7, "green_fruit_iou": None,
           "phantom_fruits_per_view": 2.0}
    worse = {**row, "fruit_iou": 0.6}
    summary = {"variants": {
        "all": {**row, "delta": {k: 0.0 for k in row}},
        "no_textures": {**worse, "delta": {"fruit_iou": -0.2, "leaf_iou": 0.0, "branch_iou": 0.0,
                                           "green_fruit_iou": None,
                                           "phantom_fruits_per_view": 0.0}}}}
    table = AblationTable(summary)
    assert "| no_textures | 0.600 (-0.200) |" in table
    assert table.count("\n") == 4
