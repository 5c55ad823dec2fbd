"""Probes from issue 23 (a hostile new user): every bad input is refused
with a clear message (naming the key path / file) or a defined status and
exit code, never a traceback; outputs are complete or absent; an evaluation
never mixes results. Fast: scenario loads, pure functions, the placeholder
plant and monkeypatched runners; no full episode.

Exit codes (lmap_drake.errors): 0 done, 1 error, 2 bad input, 3 aborted,
130 interrupted.
"""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from lmap_drake.cli import main
from lmap_drake.errors import EXIT_ABORTED, EXIT_BAD_INPUT, EXIT_ERROR, EXIT_INTERRUPTED
from lmap_drake.paths import DEFAULT_SCENARIO_FILE, REPO_ROOT
from lmap_drake.scenario import LoadScenario, ScenarioError
from lmap_drake.station.hardware_config import CalibrationError

PLACEHOLDER = "{plant_scene: {kind: placeholder}, simulation_duration: 0.05}"


def _run(capsys, *argv):
    code = main(list(argv))
    cap = capsys.readouterr()
    assert "Traceback" not in cap.err, cap.err
    return code, cap.err


# --------------------------------------------------------- 1. validation at load
@pytest.mark.parametrize("text, key", [
    ("{planner: {distances: [-0.04]}}", "planner.distances"),
    ("{planner: {distances: []}}", "planner.distances"),
    ("{planner: {method: upward, distances: []}}", "planner.distances"),
    ("{plant_scene: {occlusion: 0.0}}", "plant_scene.occlusion"),
    ("{plant_scene: {occlusion: 1.0}}", "plant_scene.occlusion"),
    ("{plant_scene: {leaf: {target_tets: 0}}}", "plant_scene.leaf.target_tets"),
    ("{plant_scene: {fruit: {size: [0.07, 0.08]}}}", "plant_scene.fruit.size"),
    ("{plant_scene: {p_W_branch_base: [0.5]}}", "plant_scene.p_W_branch_base"),
    ("{plant_scene: {leaf: {width: 0.0}}}", "plant_scene.leaf.width"),
    ("{plant_scene: {leaf: {youngs_modulus: -1.0e6}}}", "plant_scene.leaf.youngs_modulus"),
    ("{plant_scene: {fruit: {height_on_branch: 0.7}}}", "plant_scene.fruit.height_on_branch"),
    ("{plant_scene: {fruit: {variant: round}}}", "plant_scene.fruit.variant"),
    ("{plant_scene: {leaf: {shape: heart}}}", "plant_scene.leaf.shape"),
    ("{shape: {method: foo}}", "shape.method"),
    ("{deformation: {arap_method: foo}}", "deformation.arap_method"),
    ("{perception: {segmenter: magic}}", "perception.segmenter"),
    ("{planner: {method: teleport}}", "planner.method"),
    ("{planner: {energy_weight: .nan}}", "planner.energy_weight"),
    ("{planner: {num_grasps: 0}}", "planner.num_grasps"),
    ("{perception: {dbscan_min_points: 0}}", "perception.dbscan_min_points"),
    ("{shape: {min_fruit_points: 0}}", "shape.min_fruit_points"),
    ("{planner: {max_replan_turn_deg: 0}}", "planner.max_replan_turn_deg"),
    ("{robot: {X_WB: {translation: [.nan, 0, 0]}}}", "robot.X_WB"),
])
def test_bad_values_refused_at_load_naming_the_key(text, key):
    with pytest.raises(ScenarioError) as err:
        LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_text=text)
    msg = str(err.value)
    assert msg.startswith(key) and "--scenario_text" in msg, msg


def test_bad_value_in_a_file_names_the_file(tmp_path):
    f = tmp_path / "mine.yaml"
    f.write_text("Mine:\n  plant_scene:\n    leaf:\n      width: 0.0\n")
    with pytest.raises(ScenarioError) as err:
        LoadScenario(filename=f, scenario_name="Mine")
    assert "plant_scene.leaf.width" in str(err.value) and str(f) in str(err.value)


def test_duplicate_yaml_keys_are_an_error(tmp_path):
    f = tmp_path / "dup.yaml"
    f.write_text("Mine:\n  random_seed: 1\n  random_seed: 2\n")
    with pytest.raises(ScenarioError, match=r"duplicate key 'random_seed'.*dup\.yaml.*line 3"):
        LoadScenario(filename=f, scenario_name="Mine")
    with pytest.raises(ScenarioError, match="duplicate key 'planner'.*--scenario_text"):
        LoadScenario(scenario_text="{planner: {num_grasps: 3}, planner: {num_grasps: 4}}")


def test_cli_bad_value_exit_2_one_line(capsys, tmp_path):
    out = tmp_path / "o"
    code, err = _run(capsys, "run", "--output", str(out), "--scenario_text",
                     "{plant_scene: {leaf: {youngs_modulus: -5.0}}}")
    assert code == EXIT_BAD_INPUT
    assert "plant_scene.leaf.youngs_modulus must be > 0" in err and "Drake" not in err
    assert len(err.strip().splitlines()) == 1 and not out.exists()


@pytest.mark.parametrize("kind", ["missing", "directory", "malformed", "not_a_map", "binary"])
def test_cli_bad_scenario_file_names_the_file(capsys, tmp_path, kind):
    f = tmp_path / "scen.yaml"
    if kind == "directory":
        f.mkdir()
    elif kind == "malformed":
        f.write_text("Defaults:\n  planner: {num_grasps: 3\n")
    elif kind == "not_a_map":
        f.write_text("- a\n- b\n")
    elif kind == "binary":
        f.write_bytes(b"\xff\xfe\x00bad")
    code, err = _run(capsys, "run", "--scenario_file", str(f), "--output", str(tmp_path / "o"))
    assert code == EXIT_BAD_INPUT and str(f) in err, err


def test_debug_shows_the_traceback(capsys, tmp_path):
    main(["run", "--debug", "--scenario_file", str(tmp_path / "nope.yaml")])
    assert "Traceback" in capsys.readouterr().err


# -------------------------------------------- plant generator: no silent scene
def _p_WC():
    from lmap_drake.station.config import DefaultCameraConfig
    return DefaultCameraConfig().X_PB.GetDeterministicValue().translation()


@pytest.mark.parametrize("text, match", [
    ("{plant_scene: {kind: procedural, occlusion: 0.05}}", "cannot be reached"),
    ("{plant_scene: {kind: procedural, leaf: {length: 0.06, width: 0.02}}}", "hides at most"),
    ("{plant_scene: {kind: procedural, fruit: {height_on_branch: 0.45}}}", "above the branch top"),
])
def test_generated_plant_that_misses_the_request_is_an_error(text, match):
    from lmap_drake.plants.generator import GeneratePlant, PlantGenerationError
    s = LoadScenario(scenario_text=text)
    with pytest.raises(PlantGenerationError, match=match):
        GeneratePlant(s.plant_scene, _p_WC())


def test_occlusion_clamp_is_recorded():
    from lmap_drake.plants.generator import OCCLUSION_CLAMP, GeneratePlant
    s = LoadScenario(scenario_text="{plant_scene: {kind: procedural, occlusion: 0.99}}")
    m = GeneratePlant(s.plant_scene, _p_WC())
    gt = m.GroundTruthDict()
    assert gt["occlusion_clamped"] and gt["occlusion_requested"] == 0.99
    assert 0.99 - OCCLUSION_CLAMP <= gt["occlusion_predicted"] < 0.99 - 0.05


# ----------------------------------------------------------- weights, calibration
@pytest.mark.parametrize("kind", ["missing", "garbage"])
def test_weights_file_errors_name_the_file(capsys, tmp_path, kind):
    w = tmp_path / "weights.pt"
    if kind == "garbage":
        w.write_bytes(b"this is not a torch checkpoint" * 10)
    out = tmp_path / "o"
    code, err = _run(capsys, "run", "--output", str(out), "--scenario_text",
                     f"{{shape: {{weights_file: '{w}'}}}}")
    assert code == EXIT_BAD_INPUT and str(w) in err, err
    assert not out.exists() and not any(tmp_path.glob(".o.*"))


def test_calibration_nan_translation_and_other_serial(tmp_path):
    from lmap_drake.station.hardware_config import (CalibrationError, CheckCalibrationSerial,
                                                    LoadCameraCalibration)
    f = tmp_path / "calib.yaml"
    f.write_text("X_WC:\n  translation: [.nan, -0.6, 0.47]\n")
    with pytest.raises(CalibrationError, match=f"{f}.*finite"):
        LoadCameraCalibration(str(f))
    f.write_text("X_WC:\n  translation: [0.5, -0.6, 0.47]\ncamera_serial: f7777777\n")
    calib = LoadCameraCalibration(str(f))
    with pytest.raises(CalibrationError, match="f7777777.*f0000001"):
        CheckCalibrationSerial(calib, "f0000001", str(f))
    d = tmp_path / "dir.yaml"
    d.mkdir()
    with pytest.raises(CalibrationError, match="not a file"):
        LoadCameraCalibration(str(d))


@pytest.mark.parametrize("calibration, match", [
    ("X_WC:\n  translation: [0.5, -0.6, 0.47]\ncamera_serial: f7777777\n",
     "is for camera f7777777, the connected camera is f0000001"),
    ("X_WC:\n  translation: [.nan, -0.6, 0.47]\n", "fixed, finite pose"),
])
def test_dry_run_refuses_a_bad_calibration_before_anything_moves(tmp_path, scenario,
                                                                 calibration, match):
    """``--dry-run`` / ``--plan-only`` on the (fake) cell: a calibration for
    another camera or a non-finite X_WC is bad input, refused before the
    episode is built; the fake arm got no command."""
    from lmap_drake.episode import RunLmapEpisode
    from fakes.hardware import FakeRobotiqServer, MakeFakeHardwareClients
    f = tmp_path / "calib.yaml"
    f.write_text(calibration)
    scenario.hardware.camera.calibration_file = str(f)
    with FakeRobotiqServer() as server:
        clients = MakeFakeHardwareClients(scenario.hardware, q0=scenario.robot.initial_q,
                                          gripper_server=server, read_only=True)
        with pytest.raises(CalibrationError, match=match):
            RunLmapEpisode(scenario, tmp_path / "o", progress=print, hardware=True,
                           plan_only=True, clients=clients)
    assert clients.ur.servo_count == 0
    assert not (tmp_path / "o" / "episode.json").exists()


# ------------------------------------------------------------------ 2/3. outputs
def test_output_path_is_a_file(capsys, tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    code, err = _run(capsys, "run", "--output", str(f), "--scenario_text", PLACEHOLDER)
    assert code == EXIT_BAD_INPUT and str(f) in err and "not a folder" in err


def test_output_path_not_writable(capsys, tmp_path):
    if os.geteuid() == 0:
        target = Path("/proc/lmap_drake_probe/out")     # read-only even for root
    else:
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        target = ro / "out"
    code, err = _run(capsys, "run", "--output", str(target), "--scenario_text", PLACEHOLDER)
    assert code == EXIT_BAD_INPUT and str(target.parent) in err, err


def _fake_snapshot(files=("scenario.yaml", "rgb.png"), fail=None):
    def run(scenario, out, hardware=False, progress=print):
        for name in files:
            (Path(out) / name).write_text(name)
        if fail is not None:
            raise fail
        return list(files)
    return run


def test_existing_output_refused_unless_overwrite(capsys, tmp_path, monkeypatch):
    import lmap_drake.episode as E
    monkeypatch.setattr(E, "RunStationSnapshot", _fake_snapshot())
    out = tmp_path / "o"
    assert _run(capsys, "run", "--output", str(out), "--scenario_text", PLACEHOLDER)[0] == 0
    (out / "stale.txt").write_text("old")
    code, err = _run(capsys, "run", "--output", str(out), "--scenario_text", PLACEHOLDER)
    assert code == EXIT_BAD_INPUT and "--overwrite" in err and (out / "stale.txt").exists()
    code, _ = _run(capsys, "run", "--output", str(out), "--overwrite",
                   "--scenario_text", PLACEHOLDER)
    assert code == 0 and not (out / "stale.txt").exists() and (out / "rgb.png").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["o"]      # no temporary left


@pytest.mark.parametrize("error, code", [(KeyboardInterrupt(), EXIT_INTERRUPTED),
                                         (OSError(28, "No space left on device"), EXIT_ERROR)])
def test_interrupt_or_write_error_leaves_no_folder(capsys, tmp_path, monkeypatch, error, code):
    import lmap_drake.episode as E
    monkeypatch.setattr(E, "RunStationSnapshot", _fake_snapshot(fail=error))
    out = tmp_path / "o"
    got, err = _run(capsys, "run", "--output", str(out), "--scenario_text", PLACEHOLDER)
    assert got == code and not out.exists() and list(tmp_path.iterdir()) == []
    assert ("interrupted" if code == EXIT_INTERRUPTED else "No space left") in err


def test_two_runs_into_one_folder_never_mix(tmp_path):
    from lmap_drake.outputs import OutputFolder
    final = tmp_path / "o"
    a, b = OutputFolder(final), OutputFolder(final)   # both started before either ended
    ta, tb = a.__enter__(), b.__enter__()
    (ta / "episode.json").write_text("a")
    (tb / "episode.json").write_text("b")
    (tb / "scenario.yaml").write_text("b")
    a.__exit__(None, None, None)       # a finishes first, then b
    b.__exit__(None, None, None)
    assert a.final == final and b.final != final
    assert sorted(p.name for p in final.iterdir()) == ["episode.json"]
    assert (final / "episode.json").read_text() == "a"
    assert {p.read_text() for p in b.final.iterdir()} == {"b"}


def test_default_output_folder_is_unique():
    from lmap_drake.outputs import DefaultOutputFolder
    names = {DefaultOutputFolder().name for _ in range(20)}
    assert len(names) == 20 and all(n.count("-") == 2 for n in names)


def test_run_exits_3_when_the_episode_aborted(capsys, tmp_path, monkeypatch):
    import lmap_drake.episode as E

    def aborted(scenario, out, progress=print, **kw):
        (Path(out) / "episode.json").write_text(json.dumps({"status": "aborted"}))
        return ["episode.json"], "aborted"
    monkeypatch.setattr(E, "RunLmapEpisode", aborted)
    out = tmp_path / "o"
    code, err = _run(capsys, "run", "--output", str(out))
    assert code == EXIT_ABORTED and (out / "episode.json").exists()


# ------------------------------------------------------------------ 4. evaluation
@pytest.mark.parametrize("argv, match", [
    (["--scenarios", "-3"], "--scenarios"),
    (["--workers", "0"], "--workers"),
    (["--methods", ""], "--methods"),
    (["--methods", "upward", "--distances", ""], "--distances"),
    (["--methods", "upward", "--distances", "-0.04"], "--distances"),
    (["--methods", "random", "--random_seeds", "0"], "--random_seeds"),
    (["--methods", "upward", "--scenario_text", "{planner: {distances: []}}"],
     "planner.distances"),
])
def test_eval_bad_counts_exit_2(capsys, tmp_path, argv, match):
    code, err = _run(capsys, "eval", "--output", str(tmp_path / "e"), *argv)
    assert code == EXIT_BAD_INPUT and match in err, err
    assert not (tmp_path / "e" / "episodes.jsonl").exists()


def test_eval_takes_a_file_fruit_for_the_suite_and_names_a_missing_one(capsys, tmp_path):
    """``plant_scene.fruit.mesh_file`` needs ``kind: procedural``, which the
    suite's entries give and the bare override does not: the eval's early
    check must accept it (every episode's scenario is checked in full by
    ``ResolveSpecs``), and still name a file that is not there."""
    import trimesh
    from lmap_drake.cli import _CheckOverride
    f = tmp_path / "round.obj"
    trimesh.creation.icosphere(subdivisions=3, radius=0.035).export(f)
    text = "{plant_scene: {fruit: {mesh_file: %s}}}" % f
    _CheckOverride(text)
    spec = _specs(text)[0]
    assert "mesh_file" in spec["scenario_text"]
    code, err = _run(capsys, "eval", "--output", str(tmp_path / "e"), "--methods", "lmap",
                     "--scenario_text", "{plant_scene: {fruit: {mesh_file: /nope/x.obj}}}")
    assert code == EXIT_BAD_INPUT and "/nope/x.obj" in err and "not found" in err, err
    assert not (tmp_path / "e").exists()


def test_eval_random_scenes_that_cannot_be_built_with_the_overrides_exit_2(capsys, tmp_path):
    """``--scenarios N`` draws every scene with ``--scenario_text`` applied;
    when no draw can be built so, one line says why and no folder is left."""
    code, err = _run(capsys, "eval", "--output", str(tmp_path / "e"), "--methods", "lmap",
                     "--scenarios", "1", "--scenario_text",
                     "{plant_scene: {occlusion: 0.99, leaf: {length: 0.06, width: 0.03}}}")
    assert code == EXIT_BAD_INPUT, err
    assert "no buildable scene in 20 draws with the overrides" in err and "occlusion" in err
    assert len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "e").exists()


def test_torn_lines_are_set_aside_and_rerun(tmp_path):
    from lmap_drake.evaluation import tables as T
    good = {"status": "done", "eval": {"episode_id": "a|lmap|adaptive|s0|1234abcd"}}
    log = tmp_path / "episodes.jsonl"
    glued = '{"status": "done", "eval": {"episo' + json.dumps(good)   # a resume glued onto it
    log.write_text(json.dumps(good) + "\n" + glued + "\n" + '{"status": "do')
    assert T.RepairLog(log) == 2
    assert log.read_text() == json.dumps(good) + "\n"
    torn = (tmp_path / "episodes.jsonl.torn").read_text().splitlines()
    assert torn == [glued, '{"status": "do']
    assert T.RepairLog(log) == 0


def _specs(text):
    from lmap_drake.evaluation import tables as T
    from lmap_drake.evaluation.run_eval import ResolveSpecs
    specs = T.EpisodeSpecs(["small_leaf_thin_branch_round_red_heavy"], ["lmap"],
                           scenario_text=text)
    ResolveSpecs(specs, REPO_ROOT / "diagrams" / "suite.yaml")
    return specs


def test_episode_id_has_the_resolved_scenario_hash():
    a, b = _specs("{}"), _specs("{planner: {num_grasps: 3}}")
    assert a[0]["episode_id"] != b[0]["episode_id"]
    assert a[0]["episode_id"].startswith("small_leaf_thin_branch_round_red_heavy|lmap|")
    assert a[0]["episode_id"] == _specs("{}")[0]["episode_id"]      # deterministic


def test_resume_with_other_overrides_is_refused(capsys, tmp_path):
    from lmap_drake.evaluation.run_eval import _EvalEntry
    out = tmp_path / "e"
    out.mkdir()
    spec = _specs("{}")[0]
    rec = {"status": "done", "outcome": None, "eval": _EvalEntry(spec, "suite")}
    (out / "episodes.jsonl").write_text(json.dumps(rec) + "\n")
    code, err = _run(capsys, "eval", "--output", str(out), "--resume", "--methods", "lmap",
                     "--scenario_names", spec["scenario"],
                     "--scenario_text", "{planner: {num_grasps: 3}}")
    assert code == EXIT_BAD_INPUT and "would mix results" in err, err
    assert len((out / "episodes.jsonl").read_text().splitlines()) == 1


def test_eval_workers_die_with_their_parent(tmp_path):
    """SIGKILL the parent of a worker pool: its worker exits too."""
    script = tmp_path / "parent.py"
    script.write_text(
        "import concurrent.futures as cf, multiprocessing as mp, os, sys, time\n"
        "from lmap_drake.evaluation.run_eval import _init_worker\n"
        "if __name__ == '__main__':\n"
        "    pool = cf.ProcessPoolExecutor(1, mp_context=mp.get_context('spawn'),\n"
        "        initializer=_init_worker, initargs=(1, os.getpid()))\n"
        "    pid = pool.submit(os.getpid).result()\n"
        "    pool.submit(time.sleep, 120)\n"
        "    print(pid, flush=True)\n"
        "    time.sleep(120)\n")
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    try:
        worker = int(parent.stdout.readline())
        os.kill(parent.pid, signal.SIGKILL)
        parent.wait(10)
        for _ in range(50):
            try:
                os.kill(worker, 0)
            except ProcessLookupError:
                break
            time.sleep(0.1)
        else:
            os.kill(worker, signal.SIGKILL)
            pytest.fail("the worker outlived its parent")
    finally:
        if parent.poll() is None:
            parent.kill()


# --------------------------------------------------------------- 5. planner guards
def test_nan_fruit_sdf_rejects_the_candidate():
    from lmap_drake.planning.collision import LeafCollisionReason, RobotCollisionReason
    nan_sdf = lambda p: np.full(len(p), np.nan)      # noqa: E731
    pts = np.zeros((5, 3))
    assert "non-finite" in RobotCollisionReason(pts, nan_sdf, None, 0.005)
    assert "non-finite" in LeafCollisionReason(pts, pts + 0.01, nan_sdf, 0.005)
    # the baselines' "no check" margin is unaffected
    assert RobotCollisionReason(pts, nan_sdf, None, -np.inf) == ""


def test_visibility_of_a_camera_looking_away_is_bounded():
    from lmap_drake.planning.visibility import MAX_GRID_PIXELS, VisibilityModel
    rng = np.random.default_rng(0)
    fruit = rng.normal(size=(2000, 3)) * 0.03 + [0.5, 0.0, 0.3]
    X_WC = np.eye(4)
    X_WC[:3, 3] = [0.5, -0.6, 0.3]
    X_WC[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]   # optical z = -y: looks away
    vis = VisibilityModel(X_WC, fruit, 0.003)
    assert vis.shape[0] * vis.shape[1] <= MAX_GRID_PIXELS and not vis.max_seen.any()
    # the fruit spanning the camera plane: still a bounded grid
    X_WC[:3, 3] = [0.5, 0.0, 0.3]
    vis = VisibilityModel(X_WC, fruit, 0.003, image_tan=(-0.7, 0.7, -0.55, 0.55))
    assert vis.shape[0] * vis.shape[1] <= MAX_GRID_PIXELS


def test_empty_candidate_set_has_a_reason():
    from lmap_drake.planning.context import PlanningContext
    from lmap_drake.planning.result import CandidateSet
    from lmap_drake.planning.selection import SelectFromPredictions
    from lmap_drake.planning.config import PlannerConfig
    from lmap_drake.types import SceneEstimate, SemanticScene
    scene = SceneEstimate(semantic=SemanticScene())
    ctx = PlanningContext(scene, np.eye(4), None, np.zeros(6))
    r = SelectFromPredictions(ctx, CandidateSet("ok", scene), [], PlannerConfig())
    assert r.status == "no_feasible_action"
    assert r.message.startswith("no feasible action: no candidates were generated")
    assert "the 15 grasps have no pull direction within" in r.message
    dropped = [{"grasp_id": 0, "reason": "within 6 cm of the branch"}]
    r = SelectFromPredictions(ctx, CandidateSet("ok", scene, dropped_grasps=dropped), [],
                              PlannerConfig())
    assert "1 of 15 grasps were dropped (within 6 cm of the branch), the other 14" in r.message
    r = SelectFromPredictions(ctx, CandidateSet("ok", scene, dropped_grasps=dropped), [],
                              PlannerConfig(num_grasps=1))
    assert r.message.endswith("all 1 grasps were dropped (within 6 cm of the branch)")


def test_a_leaf_the_deformation_model_cannot_hang_gives_no_feasible_action(scenario):
    """A scene with no branch points: DeformationPrediction raises
    DeformationError; ActionSelection returns no_feasible_action naming the
    deformation model (a planning outcome, as in the multi-fruit path, not a
    software failure)."""
    from pydrake.systems.framework import DiagramBuilder

    from lmap_drake.deformation.action import Action
    from lmap_drake.planning.result import Candidate, CandidateSet
    from lmap_drake.systems.deformation import DeformationPrediction
    from lmap_drake.systems.planning import ActionCandidates, ActionSelection
    from lmap_drake.types import SceneEstimate, SemanticScene
    rng = np.random.default_rng(0)
    leaf = rng.uniform(-0.03, 0.03, (200, 3)) * [1, 1, 0.01] + [0.5, -0.1, 0.35]
    scene = SceneEstimate(semantic=SemanticScene(leaf_points_W=leaf))
    action = Action(leaf[0], np.eye(3), np.array([0, 0, 0.04]), grasp_id=0, direction_id=0)
    b = DiagramBuilder()
    cands = b.AddSystem(ActionCandidates(scenario))
    deform = b.AddSystem(DeformationPrediction(scenario.deformation))
    sel = b.AddSystem(ActionSelection(scenario, cands))
    b.Connect(deform.GetOutputPort("predictions"), sel.GetInputPort("predictions"))
    diagram = b.Build()
    ctx = diagram.CreateDefaultContext()
    deform.GetInputPort("scene_estimate").FixValue(deform.GetMyContextFromRoot(ctx), scene)
    deform.GetInputPort("actions").FixValue(deform.GetMyContextFromRoot(ctx), [action])
    sctx = sel.GetMyContextFromRoot(ctx)
    sel.GetInputPort("candidate_set").FixValue(
        sctx, CandidateSet("ok", scene, candidates=[Candidate(action, 1)]))
    sel.GetInputPort("ur5.position").FixValue(sctx, np.zeros(6))
    for port in ("scene_estimate",):
        cands.GetInputPort(port).FixValue(cands.GetMyContextFromRoot(ctx), scene)
    cands.GetInputPort("ur5.position").FixValue(cands.GetMyContextFromRoot(ctx), np.zeros(6))
    plan = sel.GetOutputPort("plan").Eval(sctx)
    assert plan.status == "no_feasible_action"
    assert plan.message.startswith("deformation model: no branch points")
    assert not plan.chosen


def test_perception_failure_aborts_the_controller_with_stage_error(scenario):
    """An exception in a stage the controller evaluates becomes mode
    'aborted' with status stage_error naming the stage."""
    from pydrake.common.value import AbstractValue
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder, LeafSystem

    from lmap_drake.systems.arm_controller import ArmController
    from lmap_drake.types import SemanticScene

    class Broken(LeafSystem):
        def __init__(self):
            super().__init__()
            self.DeclareAbstractOutputPort(
                "y", lambda: AbstractValue.Make(SemanticScene()), self._calc)

        def _calc(self, context, output):
            raise RuntimeError("camera image is empty")
    b = DiagramBuilder()
    broken = b.AddSystem(Broken())
    ctrl = b.AddSystem(ArmController(scenario))
    b.Connect(broken.get_output_port(), ctrl.GetInputPort("semantic_scene"))
    diagram = b.Build()
    sim = Simulator(diagram)
    cctx = ctrl.GetMyContextFromRoot(sim.get_mutable_context())
    x = np.r_[scenario.robot.initial_q, np.zeros(6)]
    ctrl.GetInputPort("ur5.state_estimated").FixValue(cctx, x)
    ctrl.GetInputPort("gripper.state_measured").FixValue(cctx, [0.085, 0.0, np.nan])
    sim.AdvanceTo(0.5)
    st = ctrl.Status(cctx)
    assert st.mode == "aborted" and st.failed_stage == "perception"
    assert st.message == "stage_error: perception: RuntimeError: camera image is empty"


# --------------------------------------------------------------- README scripts
def test_script_bad_argument_has_no_traceback(tmp_path):
    r = subprocess.run([sys.executable, str(REPO_ROOT / "scripts" / "calibrate_energy_cap.py"),
                        str(tmp_path / "missing.jsonl"), "--out", str(tmp_path / "o.json")],
                       capture_output=True, text=True,
                       timeout=120)
    assert r.returncode != 0 and "Traceback" not in r.stderr, r.stderr
    assert "missing.jsonl" in r.stderr


def test_fruit_mesh_in_millimetres_is_refused_by_the_cli(capsys, tmp_path):
    import trimesh
    f = tmp_path / "pepper_mm.stl"
    trimesh.creation.icosphere(subdivisions=3, radius=38.0).export(f)
    out = tmp_path / "o"
    code, err = _run(capsys, "run", "--output", str(out), "--scenario_text",
                     f"{{plant_scene: {{kind: procedural, fruit: {{mesh_file: '{f}'}}}}}}")
    assert code == EXIT_BAD_INPUT and str(f) in err and "plant_scene.fruit.mesh_file" in err
    assert "mesh_scale: 0.001" in err, err
    assert not out.exists()
