"""Flattened values of every scenario in ``diagrams/*.yaml`` (for
``tests/test_scenario_compat.py``). Run as a script to write
``tests/data/scenario_values.json`` from the ``lmap_drake`` on ``PYTHONPATH``:
the stored file was written from commit 8b20c62, before the configuration
moved beside its components."""
import json
import sys
from pathlib import Path

import yaml
from pydrake.common.yaml import yaml_dump_typed

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "tests" / "data" / "scenario_values.json"
# files of named scenarios (the others in diagrams/ are a calibration and a sweep)
SCENARIO_FILES = ("default.yaml", "suite.yaml", "multi_suite.yaml")


class _Loader(yaml.SafeLoader):
    pass


_Loader.add_multi_constructor(
    "!", lambda loader, suffix, node: (loader.construct_mapping(node, deep=True)
                                       if isinstance(node, yaml.MappingNode) else
                                       loader.construct_sequence(node, deep=True)
                                       if isinstance(node, yaml.SequenceNode) else
                                       loader.construct_scalar(node)))


def Flatten(data, path: str = "", out: dict | None = None) -> dict:
    """Dotted key path -> scalar or list of scalars (``a.b[2].c`` for lists
    of maps)."""
    out = {} if out is None else out
    if isinstance(data, dict):
        for k, v in data.items():
            Flatten(v, f"{path}.{k}" if path else str(k), out)
    elif isinstance(data, list) and any(isinstance(v, (dict, list)) for v in data):
        for i, v in enumerate(data):
            Flatten(v, f"{path}[{i}]", out)
    else:
        out[path] = data
    return out


def ScenarioValues(scenario) -> dict:
    from lmap_drake.scenario import Scenario
    return Flatten(yaml.load(yaml_dump_typed(scenario, schema=Scenario), Loader=_Loader))


def AllScenarioValues() -> dict:
    """{"defaults": built-in Scenario(), "scenarios": {file: {name: values
    that differ from the defaults}}}."""
    from lmap_drake.scenario import LoadScenario, Scenario
    defaults = ScenarioValues(Scenario())
    out = {"defaults": defaults, "scenarios": {}}
    for name in SCENARIO_FILES:
        path = REPO / "diagrams" / name
        out["scenarios"][name] = {}
        for scenario in yaml.load(path.read_text(), Loader=_Loader):
            values = ScenarioValues(LoadScenario(filename=path, scenario_name=scenario))
            out["scenarios"][name][scenario] = {
                k: v for k, v in values.items() if k not in defaults or defaults[k] != v}
            out["scenarios"][name][scenario]["__missing__"] = sorted(set(defaults) - set(values))
    return out


if __name__ == "__main__":
    target = Path(sys.argv[1]) if len(sys.argv) > 1 else DATA
    target.write_text(json.dumps(AllScenarioValues(), indent=0, sort_keys=True) + "\n")
    print(f"wrote {target}")
