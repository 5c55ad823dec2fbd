"""Issue 61: an evaluation's output folder is claimed before anything is
written (lock, marker with the evaluation's options), refused evaluations
change nothing in it, and two evaluations never mix in one folder. The
episodes are made by the in-process engine (``conftest.py``): no simulation."""
import json
import os
import signal
import socket
import subprocess
import sys
import time

import pytest

from lmap_drake.cli import main
from lmap_drake.errors import EXIT_BAD_INPUT
from lmap_drake.evaluation import tables as T
from lmap_drake.outputs import MARKER, FolderBusy, FolderLock, ReadMarker

SCENE = "small_leaf_thin_branch_round_red_partial"
BASE = ["eval", "--methods", "upward", "--distances", "0.04", "--scenario_names", SCENE]


def _eval(capsys, *argv):
    code = main(list(argv))
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    return code, err


def _one_line(err):
    return len(err.strip().splitlines()) == 1


def test_eval_folder_has_the_marker_with_its_options(tmp_path, capsys, inprocess_engine):
    out = tmp_path / "e"
    assert _eval(capsys, *BASE, "--output", str(out))[0] == 0
    m = ReadMarker(out)
    assert m["command"] == "eval" and m["options"]["methods"] == ["upward"]
    assert m["options"]["scenario_names"] == [SCENE] and m["options"]["seed"] == 0
    assert not list(tmp_path.glob(".e.lock"))          # the lock file left with its holder


def test_refused_random_eval_keeps_its_suite(tmp_path, capsys, inprocess_engine):
    """Defect 3: the refusal comes before suite.yaml is written."""
    out = tmp_path / "e"
    argv = ["eval", "--methods", "upward", "--distances", "0.04", "--scenarios", "1",
            "--output", str(out)]
    assert _eval(capsys, *argv, "--seed", "0")[0] == 0
    suite = (out / "suite.yaml").read_text()
    log = (out / "episodes.jsonl").read_bytes()
    code, err = _eval(capsys, *argv, "--seed", "7")
    assert code == EXIT_BAD_INPUT and str(out) in err and _one_line(err), err
    assert (out / "suite.yaml").read_text() == suite
    assert (out / "episodes.jsonl").read_bytes() == log
    # --resume with the other seed: refused naming the option (defect 4)
    code, err = _eval(capsys, *argv, "--seed", "7", "--resume")
    assert code == EXIT_BAD_INPUT and "--seed 7" in err and "--seed 0" in err, err
    assert (out / "suite.yaml").read_text() == suite
    assert (out / "episodes.jsonl").read_bytes() == log
    assert len(T.ReadRecords(out / "episodes.jsonl")) == 1


@pytest.mark.parametrize("other, option", [
    (["--seed", "3"], "--seed"),
    (["--scenario_text", "{planner: {num_grasps: 3}}"], "--scenario_text"),
    (["--methods", "upward,random"], "--methods"),
    (["--distances", "0.06"], "--distances"),
])
def test_resume_with_other_options_is_refused_naming_them(tmp_path, capsys, inprocess_engine,
                                                          other, option):
    """Defect 4: the options the log was started with are kept in the
    folder; --resume with others names the first that differs."""
    out = tmp_path / "e"
    assert _eval(capsys, *BASE, "--output", str(out))[0] == 0
    log = (out / "episodes.jsonl").read_bytes()
    argv = list(BASE)
    for i in range(0, len(other), 2):          # replace or add the option
        if other[i] in argv:
            argv[argv.index(other[i]) + 1] = other[i + 1]
        else:
            argv += other[i:i + 2]
    code, err = _eval(capsys, *argv, "--output", str(out), "--resume")
    assert code == EXIT_BAD_INPUT and f"with {option} " in err and _one_line(err), err
    assert (out / "episodes.jsonl").read_bytes() == log
    # the same options continue it; --workers may change
    assert _eval(capsys, *BASE, "--output", str(out), "--resume", "--workers", "1")[0] == 0
    assert (out / "episodes.jsonl").read_bytes() == log


def test_second_sweep_into_one_output_is_refused(tmp_path, capsys, inprocess_engine):
    """Defect 5: another sweep into a sweep's folder overwrites nothing."""
    a, b = tmp_path / "a.yaml", tmp_path / "b.yaml"
    a.write_text("planner.energy_weight: [0.0, 1.0]\n")
    b.write_text("planner.num_grasps: [3]\n")
    out = tmp_path / "s"
    assert _eval(capsys, *BASE, "--sweep", str(a), "--output", str(out))[0] == 0
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    assert {"sweep.yaml", "sweep_summary.json", "sweep_summary.png"} <= set(before)
    code, err = _eval(capsys, *BASE, "--sweep", str(b), "--output", str(out))
    assert code == EXIT_BAD_INPUT and "pass --resume" in err and _one_line(err), err
    code, err = _eval(capsys, *BASE, "--sweep", str(b), "--output", str(out), "--resume")
    assert code == EXIT_BAD_INPUT and "--sweep" in err and _one_line(err), err
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before
    assert sorted(p.name for p in out.iterdir() if p.is_dir()) == [
        "p00-energy_weight=0", "p01-energy_weight=1"]


def test_two_evals_into_one_folder_never_mix(tmp_path, capsys, inprocess_engine):
    """Defect 6: a second eval started while the first runs is refused
    (exit 2, one line naming the folder); the log has one record per
    episode."""
    out = tmp_path / "e"
    second, fake = [], inprocess_engine.make

    def make(spec):
        if not second:            # while the first eval runs its first episode
            second.append(main([*BASE, "--output", str(out), "--scenario_text",
                                "{planner: {num_grasps: 3}}"]))
            second.append(capsys.readouterr().err)
        return fake(spec)
    inprocess_engine.make = make
    assert _eval(capsys, *BASE, "--methods", "upward,random", "--random_seeds", "2",
                 "--output", str(out))[0] == 0
    code, err = second
    assert code == EXIT_BAD_INPUT and "in use by another lmap-drake command" in err, err
    assert str(out) in err and _one_line(err) and "Traceback" not in err
    recs = T.ReadRecords(out / "episodes.jsonl")
    assert len(recs) == 3 and len({r["eval"]["episode_id"] for r in recs}) == 3
    assert all("num_grasps" not in r["eval"]["scenario_text"] for r in recs)


def test_the_lock_is_held_across_processes_and_released_when_killed(tmp_path, capsys):
    out = tmp_path / "e"
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from lmap_drake.outputs import FolderLock; "
         f"lock = FolderLock({str(out)!r}); print('locked', flush=True); time.sleep(60)"],
        stdout=subprocess.PIPE, text=True, env=dict(os.environ))
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(FolderBusy, match=f"pid {holder.pid}"):
            FolderLock(out)
        code, err = _eval(capsys, *BASE, "--output", str(out))
        assert code == EXIT_BAD_INPUT and str(out) in err and _one_line(err), err
        assert not out.exists()
        os.kill(holder.pid, signal.SIGKILL)          # a crash: the kernel releases it
        holder.wait(10)
        FolderLock(out).Release()
    finally:
        if holder.poll() is None:
            holder.kill()


def test_bad_ray_address_leaves_no_folder(tmp_path, capsys):
    """Defect 21: nothing answers at --address: refused before the folder."""
    pytest.importorskip("ray")
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    out = tmp_path / "e"
    code, err = _eval(capsys, *BASE, "--engine", "ray", "--address", f"127.0.0.1:{port}",
                      "--output", str(out))
    assert code == EXIT_BAD_INPUT and "no Ray cluster answers" in err and _one_line(err), err
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_an_engine_that_fails_to_start_leaves_no_folder(tmp_path, capsys, monkeypatch):
    from lmap_drake.evaluation import run_eval
    from lmap_drake.evaluation.engines import EngineError

    def refuse(*a, **k):
        raise EngineError("cannot connect to the Ray cluster at 10.0.0.5:6379: refused")
    monkeypatch.setattr(run_eval, "MakeEngine", refuse)
    out = tmp_path / "deep" / "e"
    code, err = _eval(capsys, *BASE, "--output", str(out))
    assert code == EXIT_BAD_INPUT and "cannot connect" in err
    assert not out.exists()


def test_placeholder_scenes_are_refused_up_front(tmp_path, capsys, inprocess_engine):
    """Defect 23: exit 2 naming the scene, before any episode or folder."""
    suite = tmp_path / "suite.yaml"
    suite.write_text("real: {plant_scene: {kind: procedural}}\n"
                     "flat: {plant_scene: {kind: placeholder}}\n")
    out = tmp_path / "e"
    code, err = _eval(capsys, "eval", "--methods", "upward", "--distances", "0.04",
                      "--scenario_file", str(suite), "--output", str(out))
    assert code == EXIT_BAD_INPUT and "scenario flat" in err and "placeholder" in err, err
    assert _one_line(err) and not out.exists() and inprocess_engine.calls == []


def test_eval_refuses_a_folder_that_is_not_its_own(tmp_path, capsys, inprocess_engine):
    out = tmp_path / "thesis"
    out.mkdir()
    (out / "thesis.tex").write_text("years of work")
    code, err = _eval(capsys, *BASE, "--output", str(out))
    assert code == EXIT_BAD_INPUT and "choose another --output" in err, err
    code, err = _eval(capsys, *BASE, "--output", str(out), "--resume")
    assert code == EXIT_BAD_INPUT and "not an lmap-drake eval output" in err, err
    assert [p.name for p in out.iterdir()] == ["thesis.tex"]


def test_resume_of_a_folder_from_before_the_marker(tmp_path, capsys, inprocess_engine):
    """A log without the marker (older versions) still resumes; the marker
    is added with the options."""
    out = tmp_path / "e"
    assert _eval(capsys, *BASE, "--output", str(out))[0] == 0
    (out / MARKER).unlink()
    assert _eval(capsys, *BASE, "--output", str(out), "--resume")[0] == 0
    assert ReadMarker(out)["options"]["methods"] == ["upward"]
    assert len(T.ReadRecords(out / "episodes.jsonl")) == 1


def test_torn_line_that_is_not_utf8_is_set_aside_byte_for_byte(tmp_path):
    """Defect 25: bytes are kept as they were (not replaced), in the log and
    in ``.torn``; reading such a log skips the line."""
    good = json.dumps({"status": "done", "message": "caf\u00e9",
                       "eval": {"episode_id": "a|lmap|adaptive|s0|1234abcd"}},
                      ensure_ascii=False).encode()
    torn = b'{"status": "done", "message": "\xff\xfe", "eval": {"episode_id": "b"}}'
    log = tmp_path / "episodes.jsonl"
    log.write_bytes(good + b"\n" + torn + b"\n")
    assert len(T.ReadRecords(log)) == 1
    assert T.RepairLog(log) == 1
    assert log.read_bytes() == good + b"\n"
    assert (tmp_path / "episodes.jsonl.torn").read_bytes() == torn + b"\n"
    assert T.RepairLog(log) == 0


def test_a_log_that_is_a_folder_is_bad_input(tmp_path, capsys, inprocess_engine):
    out = tmp_path / "e"
    (out / "episodes.jsonl").mkdir(parents=True)
    code, err = _eval(capsys, *BASE, "--output", str(out), "--resume")
    assert code == EXIT_BAD_INPUT and "episodes.jsonl exists and is not a file" in err, err
    assert inprocess_engine.calls == [] and not (out / MARKER).exists()
