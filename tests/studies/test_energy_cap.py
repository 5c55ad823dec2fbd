"""lmap_drake.studies.energy_cap (scripts/calibrate_energy_cap.py): the cap
lies above every safe energy below the lowest unsafe one and below every
unsafe energy."""
import json
import runpy

from lmap_drake.paths import REPO_ROOT
from lmap_drake.studies.energy_cap import Calibrate, LoadRecords


def _rec(energy, damage=False, hazard=False):
    return {"scenario": "s", "chosen_action": {"energy": 100 * energy, "energy_per_node": energy},
            "outcome": {"leaf_damage": damage, "plant_hazard": hazard,
                        "max_petiole_force": 1.0, "max_strain_percentile": 1.0}}


def test_cap_separates_safe_from_unsafe(tmp_path):
    recs = [_rec(1e-4), _rec(1.5e-4), _rec(3e-4, hazard=True), _rec(2.5e-4, damage=True),
            _rec(4e-4), {"scenario": "no action", "status": "aborted"}]
    src = tmp_path / "episodes.jsonl"
    src.write_text("\n".join(json.dumps(r) for r in recs))
    res = Calibrate(LoadRecords([str(src)]))
    assert abs(res["max_energy_per_node"] - 2.0e-4) < 1e-12
    assert res["num_records"] == 5 and res["num_unsafe"] == 2
    assert res["correctly_separated"] == 4 and res["safe_above_cap"] == 1


def test_script_writes_the_cap_and_without_a_usable_record_exits_2(tmp_path):
    """(through the script: the JSON written, exit code 2 without a usable
    record)"""
    mod = runpy.run_path(str(REPO_ROOT / "scripts" / "calibrate_energy_cap.py"), run_name="cal")
    good = tmp_path / "good.jsonl"
    good.write_text("\n".join(json.dumps(r) for r in [_rec(1e-4), _rec(3e-4, hazard=True)]))
    assert mod["main"]([str(good), "--out", str(tmp_path / "cap.json")]) == 0
    assert json.loads((tmp_path / "cap.json").read_text())["num_records"] == 2
    src = tmp_path / "episodes.jsonl"
    src.write_text(json.dumps({"status": "aborted"}))
    assert mod["main"]([str(src), "--out", str(tmp_path / "c.json")]) == 2
