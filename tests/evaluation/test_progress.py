"""The up-front estimate (episodes, core-hours) and the progress bar with
its ETA of ``lmap-drake eval``; the run itself on an in-process engine
(``conftest.InProcessEngine``)."""
import io
import json

from lmap_drake.evaluation import progress as P
from lmap_drake.evaluation import tables as T
from lmap_drake.evaluation.run_eval import RunEvaluation
from lmap_drake.paths import DIAGRAMS_DIR

SUITE = DIAGRAMS_DIR / "suite.yaml"
SCENE = "small_leaf_thin_branch_round_red_partial"


def test_estimate_from_the_constants_and_from_recorded_medians():
    specs = T.EpisodeSpecs(["a", "b"], ["upward", "lmap"], [0.04])
    est = P.Estimate(specs, slots=2)
    core = 2 * (P.EPISODE_CORE_SECONDS["upward"] + P.EPISODE_CORE_SECONDS["lmap"])
    assert est["episodes"] == 4 and abs(est["core_seconds"] - core) < 1e-9
    assert abs(est["core_hours"] - core / 3600) < 1e-12 and est["wall_seconds"] == core / 2
    assert "constants" in est["source"]
    # resuming: the median wall time of the recorded episodes of a method
    recs = [dict(status="done", wall_seconds=w, eval={"method": "lmap"}) for w in (10, 30, 40)]
    recs.append(dict(status="error", wall_seconds=1.0, eval={"method": "lmap"}))
    assert P.EpisodeCosts(recs) == {"lmap": (30.0, 3)}
    # the CPU time of an episode is its cost when recorded (not the wall time)
    assert P.EpisodeCosts([dict(recs[0], cpu_seconds=8.0)]) == {"lmap": (8.0, 1)}
    est = P.Estimate(specs, slots=4, records=recs)
    assert est["core_seconds"] == 2 * (P.EPISODE_CORE_SECONDS["upward"] + 30.0)
    assert "medians of 3 finished record(s)" in est["source"]
    line = P.EstimateLine(P.Estimate(T.EpisodeSpecs([f"s{i}" for i in range(1000)], ["lmap"]),
                                     slots=64), "ray")
    lmap = P.EPISODE_CORE_SECONDS["lmap"]
    assert line.startswith(f"estimate: 1000 episode(s), {1000 * lmap / 3600:.2f} core-hours, "
                           f"~{P.Duration(1000 * lmap / 64)} on 64 ray slot(s)")


def test_estimate_counts_each_fruit_of_a_multi_fruit_plant():
    """ResolveSpecs marks a multi-fruit scene revealing every fruit with its
    number of targets; the estimate charges each of them."""
    from lmap_drake.evaluation.run_eval import ResolveSpecs
    specs = T.EpisodeSpecs(["three_fruits_default", "two_fruits_two_leaves_heavy"], ["lmap"])
    ResolveSpecs(specs, DIAGRAMS_DIR / "multi_suite.yaml")     # the suite reveals every fruit
    assert [s["targets"] for s in specs] == [3, 2]
    est = P.Estimate(specs, slots=2)
    assert abs(est["core_seconds"] - 5 * P.MULTI_CORE_SECONDS_PER_TARGET) < 1e-9
    one = T.EpisodeSpecs(["three_fruits_default"], ["lmap"])     # the largest fruit only
    one[0]["scenario_text"] = "{planner: {targets: largest}}"
    ResolveSpecs(one, DIAGRAMS_DIR / "multi_suite.yaml")
    assert "targets" not in one[0]


def test_eta_and_durations():
    assert P.EtaSeconds(0, 10, 5.0) is None
    assert P.EtaSeconds(2, 10, 30.0) == 120.0 and P.EtaSeconds(10, 10, 99.0) == 0.0
    assert [P.Duration(s) for s in (45, 600, 4 * 3600)] == ["45 s", "10 min", "4.0 h"]


def test_progress_bar_counts_episodes_and_keeps_lines_above_it():
    bar, said = io.StringIO(), []
    with P.Progress(3, said.append, enabled=True, file=bar) as p:
        for k in range(3):
            p.Step()
            p.Say(f"episode {k}")
    assert said == ["episode 0", "episode 1", "episode 2"]
    text = bar.getvalue()
    assert "3/3" in text and "ep" in text and "<" in text      # tqdm: n/total [elapsed<eta]
    assert P.Progress(3, said.append, file=io.StringIO()).enabled is False   # not a terminal


def test_run_prints_the_estimate_then_episodes_with_eta(tmp_path, inprocess_engine,
                                                        monkeypatch):
    specs = T.EpisodeSpecs([SCENE], ["upward"], [0.02, 0.04, 0.06])
    lines, bar = [], io.StringIO()
    real = P.Progress
    monkeypatch.setattr(P, "Progress", lambda n, say, enabled=None: real(n, say, True, bar))
    summary = RunEvaluation(specs, SUITE, tmp_path, progress=lines.append)
    monkeypatch.setattr(P, "Progress", real)
    assert summary["ran"] == 3 and summary["estimate"]["episodes"] == 3
    assert lines[0].startswith("3 episode(s), 0 already recorded; running 3 on the pool engine")
    up = P.EPISODE_CORE_SECONDS["upward"]
    assert lines[1].startswith(f"estimate: 3 episode(s), {3 * up / 3600:.2f} core-hours, "
                               f"~{P.Duration(3 * up / 2)} on 2 inprocess slot(s)")
    eps = [m for m in lines if m.startswith("[")]
    assert [m[:5] for m in eps] == ["[1/3]", "[2/3]", "[3/3]"]
    assert "; eta " in eps[0] and "; eta " not in eps[-1]
    assert "3/3" in bar.getvalue()
    # resumed with one more distance: the estimate uses the recorded median (12 s)
    more = T.EpisodeSpecs([SCENE], ["upward"], [0.02, 0.04, 0.06, 0.08])
    lines.clear()
    RunEvaluation(more, SUITE, tmp_path, resume=True, progress=lines.append, bar=False)
    assert lines[1] == ("estimate: 1 episode(s), 0.00 core-hours, ~12 s on 2 inprocess slot(s) "
                        "(medians of 3 finished record(s) in episodes.jsonl)")
    assert len(T.ReadRecords(tmp_path / "episodes.jsonl")) == 4
    assert json.loads((tmp_path / "table2.json").read_text())["upward"]["8cm"]["n"] == 1
