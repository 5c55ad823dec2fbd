"""A multi-fruit run replays fruit by fruit (``planner.targets: all``): the
replay plans on view 0 as the run's controller did before its first motion
(the fruits whose plan failed skipped, the next one planned) and compares
that sequence with the run's."""
import json

from lmap_drake.episode import ReplayRun, RunSimEpisode, SaveEpisode
from lmap_drake.episode.replay import RunFirstPlans, SameFirstPlans
from lmap_drake.paths import DIAGRAMS_DIR
from lmap_drake.scenario import DumpScenario, LoadScenario


def test_a_multi_fruit_run_replays_to_the_same_first_plans(tmp_path):
    s = LoadScenario(filename=DIAGRAMS_DIR / "multi_suite.yaml",
                     scenario_name="three_fruits_default",
                     scenario_text="{perception: {segmenter: label}}")
    assert s.planner.targets == "all"
    result = RunSimEpisode(s, plan_only=True)
    run = tmp_path / "run"
    SaveEpisode(result, run)
    DumpScenario(s, run / "scenario.yaml")
    run_seq = RunFirstPlans(run)
    assert run_seq, "the run planned no fruit"
    plan = json.loads((run / "plan.json").read_text())
    assert plan["target"]["fruit_id"] == run_seq[-1]["fruit_id"]
    _, replay = ReplayRun(run, tmp_path / "replay", progress=print)
    assert replay["first_plans"][-1]["status"] == plan["status"]
    assert replay["same_first_plans_as_run"] is True, (replay["first_plans"], run_seq)
    # a different leaf for one fruit is a different sequence
    other = [dict(r) for r in run_seq]
    other[-1]["leaf_id"] = -5
    assert not SameFirstPlans(replay["first_plans"], other)


def test_a_run_without_a_plan_has_nothing_to_compare(tmp_path):
    assert RunFirstPlans(tmp_path) is None
    (tmp_path / "episode.json").write_text(json.dumps({"targets": []}))
    assert RunFirstPlans(tmp_path) is None
    (tmp_path / "episode.json").write_text(json.dumps({"targets": [
        {"fruit_id": 3, "leaf_id": 1, "outcome": "no_feasible_action: x", "motions": []},
        {"fruit_id": 5, "leaf_id": 2, "outcome": "revealed", "motions": ["pull 4 cm"]},
        {"fruit_id": 6, "leaf_id": 0, "outcome": "revealed", "motions": ["arc"]}]}))
    seq = RunFirstPlans(tmp_path)
    assert [(r["fruit_id"], r["status"], r["action"]) for r in seq] == [
        (3, "no_feasible_action", None), (5, "ok", "pull 4 cm")]
