"""lmap_drake.studies.fruit_detection (scripts/eval_fruit_detection.py):
fruit instances matched to the true fruits, counted per threshold."""
import json
import subprocess
import sys

import numpy as np
from scipy.spatial import cKDTree

from lmap_drake.paths import REPO_ROOT
from lmap_drake.studies.fruit_detection import MatchInstances, Summarize

SCRIPT = REPO_ROOT / "scripts" / "eval_fruit_detection.py"


def _sphere_points(center, radius, n, rng):
    u = rng.normal(size=(n, 3))
    return np.asarray(center) + radius * u / np.linalg.norm(u, axis=1, keepdims=True)


def test_instances_are_matched_to_their_fruit_or_called_phantoms():
    rng = np.random.default_rng(0)
    trees = [cKDTree(_sphere_points(c, 0.03, 5000, rng)) for c in ([0, 0, 0], [0.2, 0, 0])]
    a = _sphere_points([0.2, 0, 0], 0.03, 40, rng)            # on fruit 1
    b = _sphere_points([0, 0, 0], 0.03, 12, rng)              # a small piece of fruit 0
    c = np.c_[np.linspace(0.05, 0.1, 25), np.zeros(25), np.zeros(25)]   # a stalk: no fruit
    P = np.vstack([a, b, c])
    inst = np.r_[np.full(40, 0), np.full(12, 1), np.full(25, 2)]
    rows = MatchInstances(P, np.r_[inst[:-1], -1], trees)    # one noise point
    assert [r["points"] for r in rows] == [40, 12, 24]
    assert [r["fruit"] for r in rows[:2]] == [1, 0]
    assert rows[0]["on_fruit"] == 1.0 and rows[1]["on_fruit"] == 1.0
    assert rows[2]["on_fruit"] < 0.5                                 # a phantom
    plants = {"p": {"fruits": 2, "instances": {"30": rows}}}
    (lo, hi) = Summarize(plants, [30], [10, 30])
    assert (lo["instances"], lo["fruits_seen"], lo["phantoms"]) == (3, 2, 1)
    assert (hi["instances"], hi["fruits_seen"], hi["phantoms"]) == (1, 1, 0)
    assert lo["fruits"] == hi["fruits"] == 2


def test_a_missing_scenario_file_is_named_and_nothing_is_written(tmp_path):
    out = tmp_path / "d.json"
    r = subprocess.run([sys.executable, str(SCRIPT), "--scenario_file", str(tmp_path / "no.yaml"),
                        "--out", str(out)], capture_output=True, text=True)
    assert r.returncode == 2 and "no.yaml" in r.stderr and "Traceback" not in r.stderr
    assert not out.exists()


def test_one_plant_end_to_end(tmp_path):
    out = tmp_path / "d.json"
    r = subprocess.run([sys.executable, str(SCRIPT), "--scenario_file",
                        str(REPO_ROOT / "diagrams" / "multi_suite.yaml"), "--scenario_names",
                        "three_fruits_partial", "--dbscan_min_points", "30",
                        "--min_instance_points", "30", "--out", str(out)],
                       capture_output=True, text=True, cwd=REPO_ROOT)
    assert r.returncode == 0, r.stderr[-2000:]
    d = json.loads(out.read_text())
    (row,) = d["settings"]
    assert row["fruits"] == 3 and 1 <= row["fruits_seen"] <= 3
    inst = d["plants"]["three_fruits_partial"]["instances"]["30"]
    assert row["instances"] == sum(x["points"] >= 30 for x in inst)
