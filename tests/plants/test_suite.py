"""Every scenario of diagrams/suite.yaml loads, builds (FEM leaf included),
renders, and shows its fruit partly hidden by its leaf."""
import pytest
import yaml

from lmap_drake.labels import FRUIT, LEAF, DecodeLabels
from lmap_drake.paths import DIAGRAMS_DIR
from lmap_drake.scenario import LoadScenario
from lmap_drake.plants.world import MakePlantStation

SUITE = DIAGRAMS_DIR / "suite.yaml"
NAMES = list(yaml.safe_load(SUITE.read_text()))


def test_twelve_scenarios():
    assert len(NAMES) == 12


@pytest.mark.parametrize("name", NAMES)
def test_scenario_builds_and_renders(name):
    s = LoadScenario(filename=SUITE, scenario_name=name)
    station = MakePlantStation(s)
    ctx = station.CreateDefaultContext()
    cls, _ = DecodeLabels(station.GetOutputPort("camera0.label_image").Eval(ctx).data)
    assert (cls == FRUIT).sum() > 50 and (cls == LEAF).sum() > 500


# --- RandomSuite with the episodes' overrides (lmap-drake eval --scenarios N
# --scenario_text ...) -------------------------------------------------------

def _big_pepper_file(tmp_path):
    import trimesh
    f = tmp_path / "big.stl"     # 9 x 9 x 10 cm, about 420 cm^3: larger than any drawn pepper
    m = trimesh.creation.icosphere(3, 0.045)
    m.apply_scale([1.0, 1.0, 10.0 / 9.0])
    m.export(f)
    return f


def test_random_suite_draws_are_checked_with_the_overrides(tmp_path):
    from lmap_drake.plants.suite import RandomSuite, _WhyNotBuildable
    text = "{plant_scene: {fruit: {mesh_file: %s}}}" % _big_pepper_file(tmp_path)
    plain = RandomSuite(4, seed=2)
    refused = [n for n, cfg in plain.items() if _WhyNotBuildable(cfg, text)]
    assert refused, "seed 2 no longer draws a scene the big pepper cannot be hidden in"
    checked = RandomSuite(4, seed=2, scenario_text=text)
    assert list(checked) == list(plain)          # same names, same count
    assert not any(_WhyNotBuildable(cfg, text) for cfg in checked.values())
    assert [c.leaf.length for c in checked.values()] != [c.leaf.length for c in plain.values()]
    # deterministic, and without overrides the suite is what it was
    again = RandomSuite(4, seed=2, scenario_text=text)
    assert [c.leaf.length for c in again.values()] == [c.leaf.length for c in checked.values()]
    assert [c.leaf.length for c in RandomSuite(4, seed=2, scenario_text="{}").values()] == \
        [c.leaf.length for c in plain.values()]


def test_random_suite_that_cannot_be_built_says_why():
    from lmap_drake.errors import InputError
    from lmap_drake.plants.suite import RandomSuite, SuiteError
    text = "{plant_scene: {occlusion: 0.99, leaf: {length: 0.06, width: 0.03}}}"
    with pytest.raises(SuiteError, match=r"no buildable scene in 3 draws with the overrides "
                                         r"\{plant_scene.*the last: .*occlusion") as err:
        RandomSuite(2, seed=1, max_draws=3, scenario_text=text)
    assert isinstance(err.value, InputError)


def test_random_suite_reports_each_scene_drawn():
    from lmap_drake.plants.suite import RandomSuite
    calls = []
    suite = RandomSuite(2, seed=1, on_scene=lambda: calls.append(len(calls)))
    assert len(calls) == 2 == len(suite)
