"""Scenario YAML written for 8b20c62 (before each section moved beside its
component) resolves to the same values: every scenario of every
``diagrams/*.yaml``, a run's dumped ``scenario.yaml`` and overrides with the
old keys (``tests/data/scenario_key_moves.json``: old -> new key paths)."""
import json

import pytest
from pydrake.common.yaml import yaml_dump_typed, yaml_load_typed

from lmap_drake.scenario import (MOVED_KEYS, LoadScenario, MigrateScenarioText, Scenario,
                                 ScenarioError)
from lmap_drake.shape.config import ShapeConfig
from scenario_values import DATA, REPO, SCENARIO_FILES, ScenarioValues

OLD = json.loads(DATA.read_text())
MOVES = json.loads((DATA.parent / "scenario_key_moves.json").read_text())


def _Expected(old_values: dict, explicit=()) -> dict:
    """The old flattened values under their new key paths, plus the keys
    that are new (at their defaults); a default changed on purpose
    (``changed_defaults``: new key path -> new default, each with its reason
    in the config's docs) takes its new value where the old scenario did not
    set the key (``explicit``: old key paths it set)."""
    out = {MOVES["moved"].get(k, k): v for k, v in old_values.items()}
    out.update(MOVES["added"])
    explicit = {MOVES["moved"].get(k, k) for k in explicit}
    out.update({k: v for k, v in MOVES.get("changed_defaults", {}).items()
                if k not in explicit})
    return out


def _OldScenario(file: str, name: str) -> dict:
    diff = OLD["scenarios"][file][name]
    values = {k: v for k, v in OLD["defaults"].items() if k not in diff["__missing__"]}
    values.update({k: v for k, v in diff.items() if k != "__missing__"})
    return values


def _SetIn(file: str, name: str) -> set:
    """The keys the old scenario set itself."""
    return {k for k in OLD["scenarios"][file][name] if k != "__missing__"}


def test_the_moved_keys_are_the_recorded_ones():
    assert MOVED_KEYS == MOVES["moved"]
    assert set(ScenarioValues(Scenario())) == set(_Expected(OLD["defaults"]))


def test_defaults_are_unchanged():
    assert ScenarioValues(Scenario()) == _Expected(OLD["defaults"])


@pytest.mark.parametrize("file,name", [(f, n) for f in SCENARIO_FILES
                                       for n in OLD["scenarios"][f]])
def test_every_diagrams_scenario_resolves_as_before(file, name):
    s = LoadScenario(filename=REPO / "diagrams" / file, scenario_name=name)
    assert ScenarioValues(s) == _Expected(_OldScenario(file, name), _SetIn(file, name))


def test_a_scenario_dumped_by_8b20c62_loads_with_the_same_values():
    """A run's ``scenario.yaml`` (``DumpScenario``, every key) from before
    the move replays: the old keys are read at their new place."""
    s = LoadScenario(filename=DATA.parent / "scenario_dumped_8b20c62.yaml", bare=True)
    old = _OldScenario("default.yaml", "OneOfEverything")
    assert ScenarioValues(s) == _Expected(old, explicit=set(old))   # a dump sets every key


def _Changed(v):
    """A valid value other than the default ``v``."""
    if isinstance(v, bool):
        return not v
    if isinstance(v, int):
        return v + 1
    if isinstance(v, float):
        return 1.5 * v if v else 10.0
    return [1.5 * x for x in v]


def _Text(values: dict) -> str:
    nested: dict = {}
    for key, value in values.items():
        node = nested
        *parents, leaf = key.split(".")
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = value
    return json.dumps(nested)  # JSON is YAML


def test_old_keys_in_an_override_set_the_new_ones():
    defaults = ScenarioValues(Scenario())
    old = {k: _Changed(defaults[v]) for k, v in MOVED_KEYS.items()}
    old_style = LoadScenario(scenario_text=_Text(old))
    new_style = LoadScenario(scenario_text=_Text({MOVED_KEYS[k]: v for k, v in old.items()}))
    values = ScenarioValues(old_style)
    assert all(values[MOVED_KEYS[k]] == v for k, v in old.items())
    assert yaml_dump_typed(old_style, schema=Scenario) == yaml_dump_typed(new_style,
                                                                          schema=Scenario)


def test_old_keys_in_a_file_set_the_new_ones(tmp_path):
    path = tmp_path / "old.yaml"
    path.write_text("Mine:\n  plant_scene: {kind: placeholder}\n"
                    "  shape:\n    iterations: 77\n    branch_slab: 0.02\n"
                    "    ssc: {w_sur: 2.5}\n    method: homa\n")
    s = LoadScenario(filename=path, scenario_name="Mine")
    assert (s.shape.ssc.iterations, s.shape.branch.slab, s.shape.ssc.w_sur,
            s.shape.method) == (77, 0.02, 2.5, "homa")


def test_a_key_set_both_ways_or_left_unmoved_names_the_new_key():
    with pytest.raises(ScenarioError) as err:
        LoadScenario(scenario_text="{shape: {w_ped: 0.2, ssc: {w_ped: 0.3}}}")
    assert str(err.value) == "shape.w_ped is now shape.ssc.w_ped; --scenario_text sets both"
    with pytest.raises(ScenarioError) as err:     # a merge key is not rewritten
        LoadScenario(scenario_text="{shape: {<<: {branch_mesh_res: 0.004}}}")
    assert str(err.value) == ("shape.branch_mesh_res is now shape.branch.mesh_res "
                              "(in --scenario_text)")
    assert "\n" not in str(err.value)


def test_a_section_alone_migrates_too():
    """``scripts/eval_shape.py --shape_text`` takes the ``shape`` section alone."""
    text = MigrateScenarioText("{w_sur: 2.0, branch_slab: 0.02, method: homa}", "--shape_text",
                               named=False, section="shape")
    cfg = yaml_load_typed(schema=ShapeConfig, data=text, defaults=ShapeConfig())
    assert (cfg.ssc.w_sur, cfg.branch.slab, cfg.method) == (2.0, 0.02, "homa")
