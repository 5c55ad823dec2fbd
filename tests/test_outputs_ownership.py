"""Issue 61: output folders are ours before anything is deleted. A run's
folder carries the ``.lmap_drake`` marker; ``--overwrite`` replaces only
such a folder, never the input being read (nor a folder holding it or
inside it), follows a symlinked ``--output`` without leaving a hidden link,
and two commands that could delete each other's files are never run into
one folder at once (the second exits 2 naming the folder). The episodes
are monkeypatched writers: no simulation."""
import json
import os
from pathlib import Path

import pytest

from lmap_drake.cli import main
from lmap_drake.errors import EXIT_BAD_INPUT, OutputError

PLACEHOLDER = "{plant_scene: {kind: placeholder}, simulation_duration: 0.05}"


def _run(capsys, *argv):
    code = main(list(argv))
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    return code, err


@pytest.fixture
def snapshot(monkeypatch):
    """``run`` writes ``rgb.png`` (its content: ``calls``' length) and calls
    ``during`` (if set) while its folder is being written."""
    import lmap_drake.episode as E
    state = {"calls": 0, "during": None}

    def run(scenario, out, hardware=False, progress=print):
        state["calls"] += 1
        (Path(out) / "rgb.png").write_text(str(state["calls"]))
        if state["during"] is not None:
            during, state["during"] = state["during"], None
            during()
        return ["rgb.png"]
    monkeypatch.setattr(E, "RunStationSnapshot", run)
    return state


def _files(folder):
    return sorted(p.name for p in Path(folder).iterdir())


def test_run_folder_has_the_marker(tmp_path, capsys, snapshot):
    from lmap_drake.outputs import MARKER, ReadMarker
    out = tmp_path / "o"
    assert _run(capsys, "run", "--output", str(out), "--scenario_text", PLACEHOLDER)[0] == 0
    assert _files(out) == [MARKER, "rgb.png"] and ReadMarker(out)["command"] == "run"
    assert _files(tmp_path) == ["o"]                     # no lock or temporary left


def test_overwrite_refuses_a_folder_that_is_not_ours(tmp_path, capsys, snapshot):
    """Defect 8: ``run --output FOLDER --overwrite`` deleted thesis.tex."""
    out = tmp_path / "writing"
    out.mkdir()
    (out / "thesis.tex").write_text("years of work")
    code, err = _run(capsys, "run", "--output", str(out), "--overwrite",
                     "--scenario_text", PLACEHOLDER)
    assert code == EXIT_BAD_INPUT and str(out) in err and "not an lmap-drake output" in err
    assert len(err.strip().splitlines()) == 1 and snapshot["calls"] == 0
    assert _files(out) == ["thesis.tex"] and _files(tmp_path) == ["writing"]


def test_overwrite_refuses_the_scenario_file_being_read(tmp_path, capsys, snapshot):
    out = tmp_path / "o"
    assert _run(capsys, "run", "--output", str(out), "--scenario_text", PLACEHOLDER)[0] == 0
    mine = out / "mine.yaml"
    mine.write_text("Mine: {plant_scene: {kind: placeholder}, simulation_duration: 0.05}\n")
    code, err = _run(capsys, "run", "--output", str(out), "--overwrite",
                     "--scenario_file", str(mine), "--scenario_name", "Mine")
    assert code == EXIT_BAD_INPUT and "contains the input" in err, err
    assert mine.exists()


@pytest.fixture
def fake_replay(monkeypatch):
    """``replay`` with its recording check and episode replaced: the tests
    are about the folders."""
    import lmap_drake.episode as E
    import lmap_drake.perception.recording as R
    monkeypatch.setattr(R, "LoadRecording", lambda run_dir: None)

    def replay(run_dir, out, scenario_text="{}", progress=print):
        (Path(out) / "episode.json").write_text(json.dumps({"status": "ok"}))
        return ["episode.json"], {"status": "ok"}
    monkeypatch.setattr(E, "ReplayRun", replay)


@pytest.mark.parametrize("where, what", [("same", "is the input"),
                                         ("inside", "is inside the input"),
                                         ("parent", "contains the input")])
def test_replay_refuses_an_output_overlapping_the_run(tmp_path, capsys, snapshot,
                                                      fake_replay, where, what):
    """Defect 8: ``replay RUN --output RUN --overwrite`` deleted RUN."""
    from lmap_drake.outputs import WriteMarker
    run = tmp_path / "runs" / "r1"
    assert _run(capsys, "run", "--output", str(run), "--scenario_text", PLACEHOLDER)[0] == 0
    WriteMarker(run.parent, "run")        # even a parent that is an lmap output
    before = _files(run)
    output = {"same": run, "inside": run / "replay", "parent": run.parent}[where]
    code, err = _run(capsys, "replay", str(run), "--output", str(output), "--overwrite")
    assert code == EXIT_BAD_INPUT and what in err and str(run) in err, err
    assert _files(run) == before and (run / "rgb.png").read_text() == "1"
    assert not (run / "replay").exists()
    # elsewhere it works, and --overwrite replaces that replay
    other = tmp_path / "rp"
    for extra in ([], ["--overwrite"]):
        assert _run(capsys, "replay", str(run), "--output", str(other), *extra)[0] == 0
    assert "episode.json" in _files(other)


def test_overwrite_through_a_symlink_replaces_its_target(tmp_path, capsys, snapshot):
    """Defect 25: no hidden ``.NAME.old-*`` link is left; the link stays and
    points at the new outputs."""
    target, link = tmp_path / "real", tmp_path / "link"
    assert _run(capsys, "run", "--output", str(target), "--scenario_text", PLACEHOLDER)[0] == 0
    link.symlink_to(target)
    code, _ = _run(capsys, "run", "--output", str(link), "--overwrite",
                   "--scenario_text", PLACEHOLDER)
    assert code == 0 and link.is_symlink() and link.resolve() == target.resolve()
    assert (target / "rgb.png").read_text() == "2"
    assert _files(tmp_path) == ["link", "real"]


def test_two_overwriting_runs_into_one_folder(tmp_path, capsys, snapshot):
    """Defect 7: a second ``run --overwrite`` while the first is writing is
    refused (exit 2, one line naming the folder); the first's files stay."""
    out = tmp_path / "o"
    assert _run(capsys, "run", "--output", str(out), "--scenario_text", PLACEHOLDER)[0] == 0
    second = []

    def during():
        second.append(main(["run", "--output", str(out), "--overwrite",
                            "--scenario_text", PLACEHOLDER]))
        second.append(capsys.readouterr().err)
    snapshot["during"] = during
    assert _run(capsys, "run", "--output", str(out), "--overwrite",
                "--scenario_text", PLACEHOLDER)[0] == 0
    code, err = second
    assert code == EXIT_BAD_INPUT and str(out) in err and "in use" in err, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert (out / "rgb.png").read_text() == "2" and snapshot["calls"] == 2
    assert _files(tmp_path) == ["o"]


def test_a_plain_run_while_an_overwriting_one_writes_is_refused(tmp_path, capsys, snapshot):
    """A run without --overwrite into the folder an overwriting run is
    replacing would see its outputs deleted: refused too."""
    out = tmp_path / "o"
    second = []

    def during():
        second.append(main(["run", "--output", str(out), "--scenario_text", PLACEHOLDER]))
    snapshot["during"] = during
    assert _run(capsys, "run", "--output", str(out), "--overwrite",
                "--scenario_text", PLACEHOLDER)[0] == 0
    assert second == [EXIT_BAD_INPUT] and (out / "rgb.png").read_text() == "1"


def test_lock_file_is_removed_by_its_last_holder(tmp_path):
    from lmap_drake.outputs import FolderBusy, FolderLock, LockPath
    a = FolderLock(tmp_path / "o", shared=True)
    b = FolderLock(tmp_path / "o", shared=True)
    with pytest.raises(FolderBusy, match=str(tmp_path / "o")):
        FolderLock(tmp_path / "o")
    a.Release()
    assert LockPath(tmp_path / "o").exists()
    b.Release()
    assert not LockPath(tmp_path / "o").exists()
    FolderLock(tmp_path / "o").Release()
    assert os.listdir(tmp_path) == []


# ------------------------------------------------------------------- twin
def _UserFolder(tmp_path):
    user = tmp_path / "mine"
    user.mkdir()
    (user / "calibration.yaml").write_text("my calibration\n")
    return user


@pytest.mark.parametrize("overwrite", [False, True])
def test_twin_refuses_a_folder_that_is_not_ours(tmp_path, capsys, overwrite):
    """``twin --output`` into a user's folder: exit 2 before anything is
    built, the user's calibration.yaml untouched, no lock file left."""
    user = _UserFolder(tmp_path)
    code = main(["twin", "--output", str(user), *(["--overwrite"] if overwrite else [])])
    err = capsys.readouterr().err
    assert code == EXIT_BAD_INPUT and err.count("\n") == 1, err
    assert str(user) in err and ("not an lmap-drake output" if overwrite
                                 else "exists and is not empty") in err, err
    assert (user / "calibration.yaml").read_text() == "my calibration\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine"]


def test_twin_overwrite_refuses_the_folder_of_the_scenario_file(tmp_path, capsys):
    import shutil

    from lmap_drake.outputs import WriteMarker
    from lmap_drake.paths import DEFAULT_SCENARIO_FILE
    shutil.copy(DEFAULT_SCENARIO_FILE, tmp_path / "s.yaml")
    WriteMarker(tmp_path, "twin")
    code = main(["twin", "--scenario_file", str(tmp_path / "s.yaml"), "--output",
                 str(tmp_path), "--overwrite"])
    err = capsys.readouterr().err
    assert code == EXIT_BAD_INPUT and "contains the input" in err, err
    assert (tmp_path / "s.yaml").read_text() == DEFAULT_SCENARIO_FILE.read_text()


def test_in_place_overwrite_empties_only_an_lmap_output(tmp_path):
    """``InPlaceFolder(overwrite=True)`` (the twin's folder): an lmap
    output is emptied by Start() and marked again; nothing is deleted
    before Start(); a folder another command holds is refused."""
    from lmap_drake.outputs import FolderBusy, InPlaceFolder, ReadMarker, WriteMarker
    out = tmp_path / "twin"
    out.mkdir()
    (out / "outcome.json").write_text("{}")
    (out / "sub").mkdir()
    WriteMarker(out, "twin")
    with InPlaceFolder(out, "twin", {}, overwrite=True) as folder:
        assert (out / "outcome.json").exists()
        with pytest.raises(FolderBusy):
            InPlaceFolder(out, "twin", {}, overwrite=True)
        folder.Start()
        assert sorted(p.name for p in out.iterdir()) == [".lmap_drake"]
        assert ReadMarker(out)["command"] == "twin"
    with pytest.raises(OutputError, match="exists and is not empty: pass --overwrite"):
        InPlaceFolder(out, "twin", {}, overwrite=False)     # twin without --overwrite
