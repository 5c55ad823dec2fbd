"""lmap_drake/planning/config.py: the planner's section validates on its own,
naming the key path the scenario reports."""
import pytest

from lmap_drake.planning.config import PlannerConfig, PlannerConfigError, ValidatePlannerConfig


def test_the_defaults_are_valid():
    ValidatePlannerConfig(PlannerConfig())


@pytest.mark.parametrize("change, key, detail", [
    ({"num_grasps": 0}, "planner.num_grasps", "must be >= 1, got 0"),
    ({"distances": []}, "planner.distances", "needs at least one value, got []"),
    ({"method": "foo"}, "planner.method",
     "'foo' unknown; choose one of lmap, random, upward, min_overlap"),
    ({"action_families": ["pull", "pull"]}, "planner.action_families",
     "must be a non-empty list of distinct families of 'pull', 'arc', 'twist', "
     "got ['pull', 'pull']"),
    ({"force_action": [1, 2, 0.04], "method": "random"}, "planner.force_action",
     "picks an LMAP candidate: it needs planner.method 'lmap'"),
    ({"release_opening": 0.002}, "planner.release_opening",
     "must be 0 (the approach's opening) or at least 0.003 m past the leaf, got 0.002"),
])
def test_a_bad_value_names_its_key(change, key, detail):
    with pytest.raises(PlannerConfigError) as err:
        ValidatePlannerConfig(PlannerConfig(**change))
    assert (err.value.key, err.value.detail) == (key, detail)
    assert str(err.value) == f"{key} {detail}"


def test_the_scenario_still_exports_the_class():
    from lmap_drake import scenario
    assert scenario.PlannerConfig is PlannerConfig
