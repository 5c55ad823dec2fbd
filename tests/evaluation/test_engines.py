"""``lmap-drake eval --engine ray``: the same episodes on a local Ray
instance give the same records as the process pool; a missing Ray or a
bad ``--address`` is one line and exit code 2.

Cheap episodes: the Upward baseline at one distance (no deformation
prediction) on two suite scenes, two at a time on each engine."""
import socket
import sys

import pytest

from lmap_drake.cli import main
from lmap_drake.errors import EXIT_BAD_INPUT
from lmap_drake.evaluation import tables as T
from lmap_drake.evaluation.engines import CheckAddress, EngineError, ImportRay, MakeEngine
from lmap_drake.evaluation.run_eval import RunEvaluation
from lmap_drake.paths import DIAGRAMS_DIR

SUITE = DIAGRAMS_DIR / "suite.yaml"
SCENES = ["small_leaf_thin_branch_round_red_partial", "large_leaf_thick_branch_round_red_partial"]


def _run(engine, out, lines):
    specs = T.EpisodeSpecs(SCENES, ["upward"], [0.04])
    summary = RunEvaluation(specs, SUITE, out, workers=2, engine=engine,
                            progress=lines.append, bar=False)
    assert summary["ran"] == 2 and not summary["errors"], summary["errors"]
    return {r["eval"]["episode_id"]: r for r in T.ReadRecords(out / "episodes.jsonl")}


def test_ray_gives_the_records_of_the_process_pool(tmp_path):
    """Two episodes on a local Ray instance (2 CPUs) and on the pool: the
    same ids, chosen actions, outcomes and everything else but timings."""
    pool_lines, ray_lines = [], []
    pool = _run("pool", tmp_path / "pool", pool_lines)
    ray = _run("ray", tmp_path / "ray", ray_lines)
    assert sorted(pool) == sorted(ray) and len(pool) == 2
    for eid in pool:
        a, b = pool[eid], ray[eid]
        assert a["chosen_action"] is not None and a["outcome"] is not None
        assert a["chosen_action"] == b["chosen_action"], eid
        assert a["outcome"] == b["outcome"], eid
        assert T.Deterministic(a) == T.Deterministic(b), eid
    # both engines stream: the estimate first, then one line per episode
    for lines, engine in ((pool_lines, "pool"), (ray_lines, "ray")):
        assert lines[1].startswith("estimate: 2 episode(s), ") and f"2 {engine} slot(s)" in lines[1]
        assert [m[:5] for m in lines if m.startswith("[")] == ["[1/2]", "[2/2]"]
        assert "; eta " in next(m for m in lines if m.startswith("[1/2]"))
    import ray as ray_module
    assert not ray_module.is_initialized()        # the engine stopped its instance


def test_missing_ray_is_one_line_exit_2(capsys, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)        # import ray -> ImportError
    with pytest.raises(EngineError, match=r"pip install -e '\.\[ray\]'"):
        ImportRay()
    out = tmp_path / "e"
    code = main(["eval", "--engine", "ray", "--methods", "upward", "--output", str(out)])
    err = capsys.readouterr().err
    assert code == EXIT_BAD_INPUT and "Traceback" not in err
    assert err.count("\n") == 1 and "--engine ray needs Ray" in err, err
    assert not out.exists()


def test_address_needs_ray_and_a_cluster(capsys, tmp_path):
    code = main(["eval", "--address", "127.0.0.1:6379", "--output", str(tmp_path / "e")])
    assert code == EXIT_BAD_INPUT and "--address needs --engine ray" in capsys.readouterr().err
    with pytest.raises(EngineError, match="--address must be HOST:PORT"):
        CheckAddress("nohost")
    with pytest.raises(EngineError, match="--address needs --engine ray"):
        MakeEngine("pool", address="127.0.0.1:6379")
    ImportRay(local=True)          # a local-only Ray: localhost stays the loopback address
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()                      # nothing listens there now
    with pytest.raises(EngineError, match=f"no Ray cluster answers at --address 127.0.0.1:{port}"):
        CheckAddress(f"127.0.0.1:{port}", timeout=2.0)


def test_a_suite_entry_alone_loads_the_scenario_of_the_whole_file():
    """Specs load from their suite entry's text (``SuiteEntries``: a large
    suite is not parsed once per episode) and resolve as from the file."""
    from lmap_drake.evaluation.run_eval import ScenarioHash, SuiteEntries, _LoadSpec
    for path, names, methods in [(SUITE, SCENES, ["lmap", "upward"]),
                                 (DIAGRAMS_DIR / "default.yaml", ["OneOfEverything"], ["lmap"])]:
        text = path.read_text()
        assert set(names) <= set(SuiteEntries(text))
        for spec in T.EpisodeSpecs(names, methods, [0.04], scenario_text="{random_seed: 3}"):
            spec["sweep_text"] = "{planner: {energy_weight: 0.5}}"
            assert ScenarioHash(_LoadSpec(spec, str(path), text)) == \
                ScenarioHash(_LoadSpec(spec, str(path))), spec["scenario"]
    assert SuiteEntries("[1, 2]") == {} and SuiteEntries("a: [1") == {}
