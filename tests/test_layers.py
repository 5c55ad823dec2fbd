"""The package's shape: the import-linter contracts in pyproject.toml (layers,
imports inside functions included) hold, and they catch a new upward import;
no module is over 600 lines but the UR emulator."""
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
LINT = Path(sys.executable).with_name("lint-imports")
MAX_LINES = 600
LONG_ALLOWED = {"lmap_drake/twin/ur_emulator.py"}   # a protocol emulator, kept whole

needs_lint = pytest.mark.skipif(not LINT.exists(),
                                reason="import-linter is not installed (the test extra has it)")


def _Lint(root: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(LINT), "--no-cache", "--config", str(root / "pyproject.toml")],
                          cwd=root, capture_output=True, text=True, timeout=300,
                          env={"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin"})


@needs_lint
def test_the_layer_contracts_hold():
    r = _Lint(REPO)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "2 kept, 0 broken" in r.stdout


@needs_lint
def test_an_upward_import_inside_a_function_breaks_the_layers(tmp_path):
    """An algorithm reaching up to the episode, even inside a function, is
    reported with the importing module and line."""
    shutil.copytree(REPO / "lmap_drake", tmp_path / "lmap_drake",
                    ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(REPO / "pyproject.toml", tmp_path)
    metrics = tmp_path / "lmap_drake" / "shape" / "metrics.py"
    metrics.write_text(metrics.read_text() + "\n\ndef _Upward():\n"
                       "    from lmap_drake.episode import runner  # noqa: F401\n")
    r = _Lint(tmp_path)
    assert r.returncode != 0
    assert "lmap_drake.shape is not allowed to import lmap_drake.episode" in r.stdout
    assert "lmap_drake.shape.metrics -> lmap_drake.episode" in r.stdout


def test_no_module_is_over_600_lines():
    long = {str(p.relative_to(REPO)): n for p in sorted((REPO / "lmap_drake").rglob("*.py"))
            if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert set(long) <= LONG_ALLOWED, long
