"""The scripts in ``scripts/`` are thin argparse shells around the package:
each loads (its package imports resolve) and parses its flags (``--help``
lists them and exits 0). What they run is tested beside the package code;
their exit codes where a test runs them (calibrate_energy_cap,
eval_fruit_detection, eval_shape, eval_held_leaf, train_deepsdf, make_suite).
Every script is listed here."""
import runpy

import pytest

from lmap_drake.paths import REPO_ROOT

SHELLS = {
    "ablate_segnet": ["--out", "--variants", "--count", "--seed", "--steps", "--init",
                      "--heldout", "--heldout_seed", "--workers"],
    "action_oracle": ["--out", "--scenario_file", "--scenario_names", "--top",
                      "--energy_weight", "--workers"],
    "bench_deformation": ["--out", "--leaf-npz", "--factorization", "--no-dense", "--method",
                          "--workers", "--repeats", "--relative-tolerance"],
    "bench_engines": ["--out", "--repeats", "--workers", "--scenario_names", "--methods",
                      "--distances", "--keep", "--reanalyse"],
    "bench_planner": ["--out", "--scenario_name", "--suite", "--shapes", "--plants", "--plant",
                      "--scenario_text", "--repeats", "--reference"],
    "bench_station": ["--out", "--scenario_name", "--duration", "--scenario_file", "--leaf",
                      "--scenario_text"],
    "bench_twin": ["--out", "--repeats", "--duration", "--variants", "--episodes",
                   "--compare_code"],
    "calibrate_energy_cap": ["records", "--out"],
    "eval_brush": ["--out", "--points", "--depths", "--clearance", "--hold"],
    "eval_deformation_vs_fem": ["--out", "--scenarios", "--corr_scenarios", "--corr_directions",
                                "--corr_distances", "--grasp_fallbacks",
                                "--keep_degenerate_leaf_mesh"],
    "eval_fruit_detection": ["--scenario_file", "--dbscan_min_points", "--min_instance_points",
                             "--on_fruit", "--settle", "--out"],
    "eval_hazard_prediction": ["--out", "--families", "--pool", "--then_twist", "--then_arc",
                               "--then_turn_band", "--repredict", "--hinge_bending_weight"],
    "eval_held_leaf": ["--runs", "--weights", "--out"],
    "eval_hinge": ["--runs", "--scenario_text", "--out"],
    "eval_leaf_instances": ["--render", "--scenario_file", "--views", "--out", "--class_maps",
                            "--min_pixels", "--baseline"],
    "eval_segmentation": ["--out", "--recordings", "--scenario_file", "--backends", "--scenarios",
                          "--seed", "--settle"],
    "export_plant": ["--out", "--scenario_file", "--scenario_name", "--scenario_text", "--seed",
                     "--cards", "--overwrite"],
    "eval_shape": ["--out", "--md", "--methods", "--fruit_mesh_dir", "--conditions",
                   "--figures"],
    "make_robot_models": [],
    "make_segnet_data": ["--out", "--count", "--seed", "--workers", "--arm_near_leaf",
                         "--multi", "--held_leaf", "--greenhouse"],
    "make_suite": ["--random", "--seed", "--out", "--multi", "--fruit_mesh_dir", "--greenhouse"],
    "make_test_peppers": ["--out", "--count", "--seed", "--kinds", "--no_peduncle"],
    "plan_plant": ["--scenario_file", "--scenario_name", "--scenario_text", "--out"],
    "render_multi_suite": ["--suite", "--out", "--scenario_text", "--no-push", "--push_speed",
                           "--only"],
    "train_deepsdf": ["--out_dir", "--family", "--meshes", "--mesh_scale", "--init",
                      "--time_limit_s"],
    "train_segnet": ["--data", "--out", "--steps", "--batch", "--init"],
}


@pytest.mark.parametrize("name", sorted(SHELLS))
def test_script_parses_its_flags(name, capsys):
    main = runpy.run_path(str(REPO_ROOT / "scripts" / f"{name}.py"), run_name=name)["main"]
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    usage = capsys.readouterr().out
    for flag in SHELLS[name]:
        assert flag in usage, (name, flag)


def test_every_script_is_a_listed_shell():
    assert {p.stem for p in (REPO_ROOT / "scripts").glob("*.py")} == set(SHELLS)
