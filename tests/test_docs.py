"""The documentation: a short README, a site that builds strictly, and a
scenario reference generated from the config dataclasses that lists every
key a scenario has."""
import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from pydrake.common.yaml import yaml_dump_typed

from lmap_drake.scenario import LoadDefaultScenario, RawYaml, Scenario

REPO = Path(__file__).resolve().parents[1]
# What follows a key of a Drake value type in its YAML spelling (a
# Transform's translation / rotation / base_frame, an Rgba's rgba, a
# FocalLength's x / y): the reference lists the key itself.
VALUE_SUBKEYS = {"translation", "rotation", "base_frame", "rgba", "x", "y", "deg", "rad"}


def _Reference():
    spec = importlib.util.spec_from_file_location("docs_reference",
                                                  REPO / "docs" / "hooks" / "reference.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module        # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def _LeafPaths(data, path=""):
    """Dotted leaf paths of loaded YAML; list items as ``[]``."""
    if isinstance(data, dict) and data:
        for k, v in data.items():
            yield from _LeafPaths(v, f"{path}.{k}" if path else str(k))
    elif isinstance(data, list) and data and all(isinstance(x, dict) for x in data):
        for item in data:
            yield from _LeafPaths(item, f"{path}[]")
    else:
        yield path


def _ScenarioLeafKeys(scenario) -> set[str]:
    data = RawYaml(yaml_dump_typed(scenario))
    keys = set()
    for p in _LeafPaths(data):
        parts = p.split(".")
        if parts[0] == "cameras" and len(parts) > 1:
            parts[1] = "<name>"
        keys.add(".".join(parts))
    return keys


def test_readme_is_at_most_200_lines():
    lines = (REPO / "README.md").read_text().splitlines()
    assert len(lines) <= 200, len(lines)
    text = "\n".join(lines)
    for command in ("make run", "make test"):
        assert command in text
    links = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
    local = [link for link in links if "://" not in link]
    assert local, "the README links into docs/"
    for link in local:
        assert (REPO / link).exists(), link


@pytest.mark.parametrize("make", [Scenario, LoadDefaultScenario],
                         ids=["Scenario()", "LoadDefaultScenario()"])
def test_scenario_reference_lists_every_leaf_key_of_the_default_scenario(make):
    ref = _Reference()
    listed = ref.ScenarioKeys()
    assert len(listed) == len(set(listed)), "a key is listed twice"
    page = ref.ScenarioMarkdown()
    missing = []
    for key in sorted(_ScenarioLeafKeys(make())):
        parts = key.split(".")
        found = key in listed or any(
            ".".join(parts[:i]) in listed and parts[i] in VALUE_SUBKEYS
            for i in range(1, len(parts)))
        if not found:
            missing.append(key)
    assert not missing, missing
    for key in listed:
        assert f"`{key}`" in page, key
    # documented where the dataclasses document them
    assert "max_pull_distance" in page and "hardware.ur.joint_speed_limit" in page


def test_cli_reference_lists_every_command_and_option():
    ref = _Reference()
    parser = ref.CliParser()
    page = ref.CliMarkdown()
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    assert set(sub.choices) >= {"run", "replay", "twin", "eval"}
    for name, p in sub.choices.items():
        assert f"## `lmap-drake {name}`" in page
        for action in p._actions:
            for option in action.option_strings:
                if option not in ("-h", "--help"):
                    assert option in page, (name, option)


def test_mkdocs_build_strict(tmp_path):
    pytest.importorskip("mkdocs")
    pytest.importorskip("material")
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
        cwd=REPO, capture_output=True, text=True, timeout=600,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert result.returncode == 0, result.stdout + result.stderr
    for page in ("reference/scenario", "reference/cli", "reference/file-formats",
                 "tutorials/first-episode", "how-to/hardware-bring-up",
                 "explanation/multi-fruit"):
        assert (tmp_path / "site" / page / "index.html").is_file(), page
