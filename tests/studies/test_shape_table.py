"""lmap_drake.studies.shape_table (scripts/eval_shape.py) with
fruit_mesh_dir: pepper meshes from a folder in the suite's scenes, the
usual JSON layout plus per-fruit rows (kept cheap: one tiny mesh, one
scene, 40 iterations)."""
import json

import numpy as np

from lmap_drake.paths import REPO_ROOT
from lmap_drake.plants.pepper_meshes import MakeTestPepper
from lmap_drake.studies.shape_table import RunShapeTable, ShapeTableOptions


def test_eval_shape_on_a_folder_of_meshes(tmp_path):
    d = tmp_path / "peppers"
    d.mkdir()
    fruit, ped = MakeTestPepper("sculpted", np.random.default_rng(2), True)
    fruit.export(d / "tiny.ply")
    ped.export(d / "tiny.peduncle.ply")
    (d / "notes.txt").write_text("not a mesh")
    out = tmp_path / "shape.json"
    RunShapeTable(ShapeTableOptions(fruit_mesh_dir=str(d), out=str(out), iterations=40,
                                    scenario_names="small_leaf_thin_branch_round_red_heavy"))
    res = json.loads(out.read_text())
    assert res["source"] == "suite+files" and res["skipped"] == []
    assert set(res["fruits"]) == {"tiny"}
    assert res["fruits"]["tiny"]["peduncle_file"].endswith("tiny.peduncle.ply")
    assert abs(res["fruits"]["tiny"]["volume_cm3"] - fruit.volume * 1e6) < 0.01 * fruit.volume * 1e6
    for m in ("supeps", "homa", "ssc"):
        for cond in ("initial_occlusion", "without_occlusion"):
            for k in ("chamfer_cm", "volume_err_cm3", "center_err_cm", "angle_err_deg",
                      "seconds"):
                assert np.isfinite(res[m][cond][k])
                assert res["per_fruit"]["tiny"][m][cond][k] == res[m][cond][k]
    for m in ("homa", "ssc"):     # the hypothesis sets' volume intervals
        for cond in ("initial_occlusion", "without_occlusion"):
            assert 0.0 <= res[m][cond]["volume_interval_coverage"] <= 1.0
            assert res[m][cond]["volume_interval_width"] >= 0.0
    assert "volume_interval_coverage" not in res["supeps"]["initial_occlusion"]
    for r in res["rows"]:
        if r["method"] != "supeps":
            lo, hi = r["volume_interval_cm3"]
            assert lo <= hi and r["volume_in_interval"] == (lo <= r["gt_volume_cm3"] <= hi)
    assert {r["fruit"] for r in res["rows"]} == {"tiny"}
    for r in res["rows"]:   # the centre error split along the view ray, up and sideways
        split = np.linalg.norm([r["center_depth_cm"], r["center_up_cm"], r["center_side_cm"]])
        assert r["center_side_cm"] >= 0 and abs(split - r["center_err_cm"]) < 1e-3
    assert len(res["rows"]) == 6
    assert "| tiny |" in (tmp_path / "shape.md").read_text()
    # one picture per condition of the fruit's first case, nothing partial left
    pics = sorted(p.name for p in (tmp_path / "shape_figures").iterdir())
    assert pics == [f"tiny@small_leaf_thin_branch_round_red_heavy_{c}.png"
                    for c in ("initial_occlusion", "without_occlusion")]
    assert res["figures"] == str(tmp_path / "shape_figures")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["peppers", "shape.json", "shape.md",
                                                         "shape_figures"]


def test_eval_shape_tables_only_the_conditions_asked_for(tmp_path):
    d = tmp_path / "peppers"
    d.mkdir()
    fruit, _ = MakeTestPepper("blob", np.random.default_rng(3), False)
    fruit.export(d / "one.obj")
    out = tmp_path / "shape.json"
    RunShapeTable(ShapeTableOptions(fruit_mesh_dir=str(d), out=str(out), iterations=20,
                                    methods="ssc", conditions="initial_occlusion", figures=0,
                                    scenario_names="small_leaf_thin_branch_round_red_heavy"))
    assert not (tmp_path / "shape_figures").exists()
    md = (tmp_path / "shape.md").read_text()
    assert "| initial occlusion | SSC |" in md
    assert "without occlusion" not in md and "nan" not in md


def test_eval_shape_refuses_a_bad_mesh_before_any_work(tmp_path, capsys):
    import subprocess
    import sys
    d = tmp_path / "peppers"
    d.mkdir()
    fruit, _ = MakeTestPepper("bent", np.random.default_rng(0), False)
    fruit.apply_scale(1000.0).export(d / "in_mm.stl")
    r = subprocess.run([sys.executable, str(REPO_ROOT / "scripts" / "eval_shape.py"),
                        "--fruit_mesh_dir", str(d), "--out", str(tmp_path / "s.json")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    assert "in_mm.stl" in r.stderr and "mesh_scale: 0.001" in r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "s.json").exists()
