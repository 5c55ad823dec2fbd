"""``lmap-drake eval --sweep FILE``: the grid file's parsing and its error
messages (naming the file and the key, before anything runs), the grid
points, and a whole sweep's folders, tables and summary on an in-process
engine (``conftest.InProcessEngine``)."""
import json

import pytest

from lmap_drake.cli import main
from lmap_drake.errors import EXIT_BAD_INPUT
from lmap_drake.evaluation import sweep as S
from lmap_drake.paths import DIAGRAMS_DIR

SCENE = "small_leaf_thin_branch_round_red_partial"


def test_grid_is_the_cartesian_product_in_file_order():
    sweep = S.ParseSweep("planner.energy_weight: [0, 0.5]\n"
                         "perception.segmenter: [label, segnet]\n", "g.yaml")
    points = S.GridPoints(sweep)
    assert points == [{"planner.energy_weight": w, "perception.segmenter": s}
                      for w in (0, 0.5) for s in ("label", "segnet")]
    assert S.OverrideText(points[1]) == \
        "{planner: {energy_weight: 0}, perception: {segmenter: segnet}}"
    assert S.OverrideText({"planner.energy_weight": 0.5, "planner.distances": [0.02, 0.04]}) \
        == "{planner: {energy_weight: 0.5, distances: [0.02, 0.04]}}"
    assert [S.PointLabel(i, p) for i, p in enumerate(points)][:2] == \
        ["p00-energy_weight=0,segmenter=label", "p01-energy_weight=0,segmenter=segnet"]
    assert S.PointLabel(3, {"planner.distances": [0.02, 0.04]}) == "p03-distances=0.02_0.04"


def test_example_sweep_file_checks():
    sweep = S.LoadSweep(DIAGRAMS_DIR / "sweep_energy_weight.yaml")
    assert sweep == [("planner.energy_weight", [0.0, 0.5, 1.0, 2.0])]
    assert len(S.CheckPoints(sweep, "x")) == 4


@pytest.mark.parametrize("text, match", [
    ("[1, 2]", "maps dotted scenario keys to lists"),
    ("{}", "maps dotted scenario keys to lists"),
    ("planner.energy_weight: 1", "planner.energy_weight needs a non-empty list"),
    ("planner.energy_weight: []", "planner.energy_weight needs a non-empty list"),
    ("planner.energy_weight: [1, 1.0]", "planner.energy_weight lists 1.0 twice"),
    ("'planner energy': [1]", "'planner energy' is not a dotted scenario key"),
    ("planner.method: [lmap]", "planner.method cannot be swept"),
    ("planner: [{}]\nplanner.energy_weight: [1]", "planner and planner.energy_weight overlap"),
    ("a: [1]\na: [2]", "duplicate key 'a' in g.yaml"),
    ("a: [1", "g.yaml is not valid YAML"),
])
def test_bad_grid_forms_name_the_file_and_key(text, match):
    with pytest.raises(S.SweepError, match=match) as err:
        S.ParseSweep(text, "g.yaml")
    assert "g.yaml" in str(err.value)


@pytest.mark.parametrize("text, match", [
    ("planner.energy_wieght: [1]", "planner.energy_wieght = 1: unknown key"),
    ("planner.num_grasps: [15, 0]", "planner.num_grasps = 0: planner.num_grasps must be >= 1"),
    ("planner.energy_weight: [abc]", "planner.energy_weight = 'abc': could not load"),
    ("plant_scene.occlusion: [0.5, 1.5]", "plant_scene.occlusion = 1.5: plant_scene.occlusion "
                                          "must be in"),
])
def test_bad_keys_and_values_are_refused_before_anything_runs(capsys, tmp_path, text, match):
    grid = tmp_path / "grid.yaml"
    grid.write_text(text)
    with pytest.raises(S.SweepError, match=match):
        S.CheckPoints(S.LoadSweep(grid), str(grid))
    out = tmp_path / "e"
    code = main(["eval", "--methods", "upward", "--distances", "0.04", "--scenario_names", SCENE,
                 "--sweep", str(grid), "--output", str(out)])
    err = capsys.readouterr().err
    assert code == EXIT_BAD_INPUT and str(grid) in err and match.split(" =")[0] in err, err
    assert "Traceback" not in err and not out.exists()


def test_missing_sweep_file(capsys, tmp_path):
    code = main(["eval", "--sweep", str(tmp_path / "nope.yaml"), "--output", str(tmp_path / "e")])
    assert code == EXIT_BAD_INPUT and "sweep file not found" in capsys.readouterr().err


def test_sweep_writes_a_folder_per_point_and_a_summary(tmp_path, capsys, inprocess_engine):
    grid = tmp_path / "grid.yaml"
    grid.write_text("planner.energy_weight: [0.0, 1.0, 2.0]\n")
    out = tmp_path / "sweep"
    argv = ["eval", "--methods", "upward,lmap", "--distances", "0.04", "--scenario_names", SCENE,
            "--sweep", str(grid), "--output", str(out)]
    assert main(argv) == 0
    labels = ["p00-energy_weight=0", "p01-energy_weight=1", "p02-energy_weight=2"]
    assert sorted(p.name for p in out.iterdir() if p.is_dir()) == labels
    for lab in labels:
        assert (out / lab / "tables.md").exists() and (out / lab / "table2.json").exists()
        assert len((out / lab / "episodes.jsonl").read_text().splitlines()) == 2
    # every point's episodes carry its override, applied after the method's own
    assert len(inprocess_engine.calls) == 6
    lmap = [s for s in inprocess_engine.calls if s["method"] == "lmap"]
    assert [s["sweep_text"] for s in lmap] == [f"{{planner: {{energy_weight: {w}}}}}"
                                               for w in ("0.0", "1.0", "2.0")]
    assert len({s["episode_id"] for s in lmap}) == 3            # other resolved scenarios
    data = json.loads((out / "sweep_summary.json").read_text())
    assert data["keys"] == ["planner.energy_weight"] and len(data["points"]) == 3
    p = data["points"][2]
    assert p["values"] == {"planner.energy_weight": 2.0} and p["folder"] == labels[2]
    assert p["all"]["n"] == 2 and p["all"]["safe_fraction"] == 1.0
    assert p["by_method"]["lmap"]["visibility_final"] == pytest.approx(1.0)
    assert data["points"][0]["by_method"]["upward"]["success_fraction"] == 0.0  # 0.9 < 0.95
    assert (out / "sweep_summary.png").stat().st_size > 5000
    assert (out / "sweep.yaml").read_text() == grid.read_text()
    # --resume runs nothing new; without it the finished sweep is refused
    assert main(argv + ["--resume"]) == 0 and len(inprocess_engine.calls) == 6
    capsys.readouterr()
    assert main(argv) == EXIT_BAD_INPUT and "pass --resume" in capsys.readouterr().err
