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
