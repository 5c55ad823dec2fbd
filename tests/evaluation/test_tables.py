"""Aggregation of episode records into the Table II-V analogues, on
hand-made records (no simulation)."""
import json

import pytest

from lmap_drake.evaluation import report as R
from lmap_drake.evaluation import tables as T


def rec(method="lmap", distance=None, scenario="s0", seed=0, v0=0.4, v1=1.0, damage=False,
        hazard=False, collision=False, status="done", shape_final=None, shape_initial=None,
        stages=None, moved=0.06, wall=100.0):
    spec = dict(scenario=scenario, method=method, distance=distance, seed=seed,
                energy_weight=T.LMAP_METHODS.get(method))
    spec["episode_id"] = T.EpisodeId(spec)
    return {"status": status, "message": "", "eval": spec,
            "outcome": {"leaf_damage": damage, "plant_hazard": hazard,
                        "fruit_collision": collision, "visibility_initial": v0,
                        "visibility_final": v1},
            "chosen_action": {"distance": moved} if moved is not None else None,
            "shape_initial": shape_initial, "shape_final": shape_final,
            "stage_seconds": stages or {}, "wall_seconds": wall}


def err(method="lmap", scenario="s9", distance=None, seed=0):
    spec = dict(scenario=scenario, method=method, distance=distance, seed=seed,
                energy_weight=None)
    spec["episode_id"] = T.EpisodeId(spec)
    return {"status": "error", "message": "RuntimeError: boom", "eval": spec}


def test_episode_specs_counts_and_overrides():
    specs = T.EpisodeSpecs(["a", "b"], random_seeds=5)
    per = {}
    for s in specs:
        per[s["method"]] = per.get(s["method"], 0) + 1
    # Table II per scenario: 5 x 4 random, 4 upward, 4 min-overlap, 1 + 1 LMAP
    assert per == {"random": 40, "upward": 8, "min_overlap": 8, "lmap": 2, "lmap_lambda0": 2}
    assert len({s["episode_id"] for s in specs}) == len(specs) == 2 * 30
    up = next(s for s in specs if s["method"] == "upward" and s["distance"] == 0.06)
    assert T.ScenarioOverride(up) == "{planner: {method: upward, distances: [0.06]}, " \
                                     "random_seed: 0}"
    l0 = next(s for s in specs if s["method"] == "lmap_lambda0")
    assert T.ScenarioOverride(l0) == "{planner: {method: lmap, energy_weight: 0.0, max_energy_per_node: 0.0}, " \
                                     "random_seed: 0}"
    seeds = sorted(s["seed"] for s in specs if s["method"] == "random" and s["scenario"] == "a"
                   and s["distance"] == 0.02)
    assert seeds == [0, 1, 2, 3, 4]
    with pytest.raises(ValueError):
        T.EpisodeSpecs(["a"], ["lmap", "nope"])


def test_override_loads_as_a_scenario():
    from lmap_drake.paths import DIAGRAMS_DIR
    from lmap_drake.scenario import LoadScenario
    spec = T.EpisodeSpecs(["small_leaf_thin_branch_round_red_heavy"], ["min_overlap"],
                          [0.04], seed=3)[0]
    s = LoadScenario(filename=DIAGRAMS_DIR / "suite.yaml", scenario_name=spec["scenario"],
                     scenario_text=T.ScenarioOverride(spec))
    assert s.planner.method == "min_overlap" and s.planner.distances == [0.04]
    assert s.random_seed == 3


def test_unsafe_trials_count_the_initial_visibility():
    rs = [rec("upward", 0.06, "s0", v0=0.4, v1=1.0),
          rec("upward", 0.06, "s1", v0=0.2, v1=0.9, hazard=True),   # counts 0.2
          rec("upward", 0.06, "s2", v0=0.5, v1=0.8, collision=True),  # counts 0.5
          rec("upward", 0.06, "s3", v0=0.3, v1=0.7, damage=True)]  # counts 0.3
    row = T.Table2(rs)["upward"]["6cm"]
    assert row["visibility_mean"] == pytest.approx((1.0 + 0.2 + 0.5 + 0.3) / 4)
    assert row["visibility_std"] == pytest.approx(
        float(__import__("numpy").std([1.0, 0.2, 0.5, 0.3])))
    assert row["visibility_initial_mean"] == pytest.approx(0.35)


def test_safe_rate_arithmetic_and_errors_apart():
    rs = [rec("min_overlap", 0.08, f"s{i}") for i in range(5)]
    rs += [rec("min_overlap", 0.08, "s5", hazard=True, collision=True),
           rec("min_overlap", 0.08, "s6", hazard=True),
           rec("min_overlap", 0.08, "s7", collision=True),
           rec("min_overlap", 0.08, "s8", status="aborted", v1=0.4),  # no action: safe
           err("min_overlap", "s9", 0.08)]
    row = T.Table2(rs)["min_overlap"]["8cm"]
    assert row["n"] == 9 and row["n_errors"] == 1 and row["n_not_done"] == 1
    assert row["safe"] == 6 and row["safe_rate"] == pytest.approx(6 / 9)
    assert row["plant_hazard"] == 2 and row["plant_hazard_rate"] == pytest.approx(2 / 9)
    assert row["fruit_collision"] == 2 and row["fruit_collision_rate"] == pytest.approx(2 / 9)


def test_table2_rows_by_method_and_distance_and_lmap_distance():
    rs = [rec("random", d, "s0", seed=k) for d in (0.02, 0.08) for k in range(3)]
    rs += [rec("lmap", None, "s0", moved=0.06), rec("lmap", None, "s1", moved=0.08, v0=0.6)]
    t2 = T.Table2(rs)
    assert list(t2["random"]) == ["2cm", "8cm"] and t2["random"]["2cm"]["n"] == 3
    assert t2["lmap"][T.ADAPTIVE]["move_distance_cm_mean"] == pytest.approx(7.0)
    # initial visibility: per-scenario mean first (s0 has 7 records at 0.4)
    assert t2["initial_visibility"]["mean"] == pytest.approx(0.5)
    assert t2["initial_visibility"]["scenarios"] == 2


def test_resume_keeps_the_latest_record_and_reruns_errors():
    a, b = rec("lmap", scenario="s0"), err("lmap", "s1")
    a2 = rec("lmap", scenario="s0", v1=0.5)
    assert T.CompletedIds([a, b]) == {a["eval"]["episode_id"]}
    row = T.Table2([a, b, a2])["lmap"][T.ADAPTIVE]
    assert row["n"] == 1 and row["n_errors"] == 1 and row["visibility_mean"] == 0.5


def test_table3_means_of_final_and_initial_shape():
    f1 = dict(chamfer_cm=0.6, volume_err_cm3=20.0, center_err_cm=0.3, angle_err_deg=10.0)
    f2 = dict(chamfer_cm=0.8, volume_err_cm3=30.0, center_err_cm=0.5, angle_err_deg=14.0)
    i1 = dict(chamfer_cm=2.0, volume_err_cm3=90.0, center_err_cm=1.0, angle_err_deg=40.0)
    rs = [rec("lmap", scenario="s0", shape_final=f1, shape_initial=i1),
          rec("lmap", scenario="s1", shape_final=f2, shape_initial=None), err("lmap")]
    t3 = T.Table3(rs)["lmap"]
    assert t3["final"]["n"] == 2 and t3["final"]["chamfer_cm"] == pytest.approx(0.7)
    assert t3["final"]["angle_err_deg"] == pytest.approx(12.0)
    assert t3["initial"]["n"] == 1 and t3["initial"]["volume_err_cm3"] == pytest.approx(90.0)


def test_table4_stage_means_with_paper_names():
    st1 = dict(segmentation_s=5.0, shape_completion_s=14.0, generation_collision_s=3.0,
               deformation_s=60.0, visibility_s=13.0, reestimation_s=10.0, total_s=999.0)
    st2 = dict(st1, segmentation_s=7.0, deformation_s=64.0)
    t4 = T.Table4([rec("lmap", scenario="s0", stages=st1, wall=100.0),
                   rec("lmap", scenario="s1", stages=st2, wall=120.0)])["lmap"]
    assert t4["semantic_segmentation"] == pytest.approx(6.0)
    assert t4["fruit_completion"] == pytest.approx(14.0)
    assert t4["deformation_simulation"] == pytest.approx(62.0)
    assert t4["visibility_checking"] == pytest.approx(13.0)
    assert t4["branch_completion"] is None
    assert t4["total"] == pytest.approx(6.0 + 14.0 + 3.0 + 62.0 + 13.0 + 10.0)
    assert t4["episode_wall"] == pytest.approx(110.0)
    assert t4["action_planning_total"] == pytest.approx(999.0)


def test_table5_partitions_lambda_rows():
    rs = [rec("lmap", scenario=f"s{i}") for i in range(3)]
    rs += [rec("lmap", scenario="s3", v1=0.9)]                       # insufficient
    rs += [rec("lmap_lambda0", scenario="s0", damage=True, v1=1.0),
           rec("lmap_lambda0", scenario="s1", damage=True, hazard=True),
           rec("lmap_lambda0", scenario="s2", hazard=True),          # other unsafe
           rec("lmap_lambda0", scenario="s3", v1=0.95), err("lmap_lambda0")]
    t5 = T.Table5(rs)
    assert list(t5) == ["lmap_lambda0", "lmap"]
    l1, l0 = t5["lmap"], t5["lmap_lambda0"]
    assert (l1["success"], l1["leaf_damage"], l1["insufficient_visibility"],
            l1["other_unsafe"], l1["n"]) == (3, 0, 1, 0, 4)
    assert (l0["success"], l0["leaf_damage"], l0["insufficient_visibility"],
            l0["other_unsafe"], l0["n"], l0["n_errors"]) == (1, 2, 0, 1, 4, 1)
    assert l1["energy_weight"] == 1.0 and l0["energy_weight"] == 0.0
    assert T.Table5(rs, threshold=0.85)["lmap"]["success"] == 4


def test_write_tables_json_markdown_plots(tmp_path):
    shape = dict(chamfer_cm=0.7, volume_err_cm3=24.0, center_err_cm=0.3, angle_err_deg=11.0)
    rs = [rec("lmap", scenario="s0", shape_final=shape, shape_initial=shape,
              stages=dict(segmentation_s=1.0)),
          rec("lmap_lambda0", scenario="s0", damage=True),
          rec("upward", 0.06, "s0", v1=0.6), err("random", "s0", 0.02)]
    log = tmp_path / "episodes.jsonl"
    log.write_text("".join(json.dumps(r) + "\n" for r in rs) + '{"torn')
    records = T.ReadRecords(log)
    assert len(records) == 4
    files = R.WriteTables(records, tmp_path, notes="partial")
    for k in ("table2", "table3", "table4", "table5"):
        assert f"{k}.json" in files and (tmp_path / f"{k}.png").stat().st_size > 1000
    t2 = json.loads((tmp_path / "table2.json").read_text())
    assert set(t2) == {"random", "upward", "lmap", "lmap_lambda0", "initial_visibility"}
    assert t2["random"]["2cm"]["n"] == 0 and t2["random"]["2cm"]["n_errors"] == 1
    md = (tmp_path / "tables.md").read_text()
    assert "Table II" in md and "| upward | 6 cm | 1 / 1 |" in md and "partial" in md
    assert "| lmap | 1 | 1 / 1 |" in md


def test_runner_records_failed_episodes_and_resumes(tmp_path):
    """The runner (worker processes) turns an exception into an ``error``
    record, writes the tables anyway, and ``resume`` re-runs only errors."""
    from lmap_drake.evaluation.run_eval import RunEvaluation, RunOneEpisode
    from lmap_drake.paths import DIAGRAMS_DIR
    suite = DIAGRAMS_DIR / "suite.yaml"
    specs = T.EpisodeSpecs(["no_such_scenario"], ["upward"], [0.06])
    r = RunOneEpisode(specs[0], str(suite))
    assert r["status"] == "error" and "no_such_scenario" in r["message"]
    assert r["eval"]["episode_id"] == specs[0]["episode_id"]
    lines = []
    out = RunEvaluation(specs, suite, tmp_path, workers=1, progress=lines.append)
    assert out["ran"] == 1 and len(out["errors"]) == 1
    assert any("no_such_scenario upward 6cm seed 0: error" in m for m in lines)
    assert (tmp_path / "tables.md").exists()
    with pytest.raises(FileExistsError):
        RunEvaluation(specs, suite, tmp_path, workers=1, progress=lines.append)
    # a finished record is skipped on resume
    ok = rec("upward", 0.06, "no_such_scenario")
    with open(tmp_path / "episodes.jsonl", "a") as f:
        f.write(json.dumps(ok) + "\n")
    out = RunEvaluation(specs, suite, tmp_path, workers=1, resume=True, progress=lines.append)
    assert out["ran"] == 0 and out["skipped"] == 1


def test_specs_carry_the_user_override():
    specs = T.EpisodeSpecs(["a"], ["lmap"], scenario_text="{planner: {max_energy_per_node: 0.0}}")
    assert [s["scenario_text"] for s in specs] == ["{planner: {max_energy_per_node: 0.0}}"]


def test_fruit_table_counts_reveals_among_the_fruits_one_leaf_can_reveal():
    def fruit(v1, ceiling, chamfer=0.2):
        return {"visibility_initial": 0.2, "visibility_final": v1, "one_leaf_ceiling": ceiling,
                "shape_initial": {"chamfer_cm": 1.0}, "shape_final": {"chamfer_cm": chamfer}}
    a = rec(scenario="p0")
    a["fruits"] = [fruit(0.95, 1.0), fruit(0.7, 0.75), fruit(0.5, 1.0)]
    a["fruits"][1]["visibility_union"] = 0.93      # two leaves moved in turn: seen over two views
    a["fruits"][1]["reveals"] = [{"motions": 1}, {"motions": 2}]
    a["fruits"][2]["reveals"] = [{"motions": 1}, {"motions": 0}]   # the second found no action
    b = rec(scenario="p1")
    b["fruits"] = [fruit(0.92, 0.8), fruit(1.0, 1.0)]
    b["fruits"][1].pop("one_leaf_ceiling")        # an older record: counted as reachable
    t = T.FruitTable([a, b])["lmap"]["adaptive"]
    assert t["fruits"] == 5 and t["revealed"] == 3
    assert t["one_leaf_reachable"] == 3 and t["revealed_of_reachable"] == 2
    assert t["revealed_union"] == 4         # records without it count their final view
    assert t["revealed_again"] == 1
    # the final shape over every fruit with an estimate, and over the moved ones
    a["fruits"][0]["action"] = {"family": "pull"}
    a["fruits"][2].update(action={"family": "arc"}, shape_final={"chamfer_cm": 0.4})
    t = T.FruitTable([a, b])["lmap"]["adaptive"]
    assert abs(t["shape_final"]["chamfer_cm"]["mean"] - 0.24) < 1e-9
    assert abs(t["shape_final_moved"]["chamfer_cm"]["mean"] - 0.3) < 1e-9
    assert t["shape_final_moved"]["chamfer_cm"]["n"] == 2
    md = R.FruitMarkdown(T.FruitTable([a, b]))
    assert "| 3 (0.60) | 2 of 3 | 4 | 1 |" in md
