"""``lmap-drake run`` end to end on the default scenario."""
import pytest

from lmap_drake.cli import main


def test_run_writes_outputs(tmp_path):
    out = tmp_path / "run"
    assert main(["run", "--output", str(out), "--scenario_text",
                 "{simulation_duration: 0.2}"]) == 0
    for name in ["rgb.png", "depth.png", "label.png", "scenario.yaml", "scene.html"]:
        assert (out / name).stat().st_size > 0, name
    assert "simulation_duration: 0.2" in (out / "scenario.yaml").read_text()
    assert "<html" in (out / "scene.html").read_text()[:2000].lower()


def test_run_rejects_bad_key(tmp_path, capsys):
    assert main(["run", "--output", str(tmp_path), "--scenario_text", "{robto: {}}"]) == 2
    assert "robto" in capsys.readouterr().err


def test_run_hardware_not_available(tmp_path, capsys, monkeypatch):
    import sys
    monkeypatch.setitem(sys.modules, "pyrealsense2", None)   # never reach a device
    assert main(["run", "--hardware", "--output", str(tmp_path)]) == 1
    assert "hardware station" in capsys.readouterr().err


# --------------------------------------------------------------- run / replay options
@pytest.mark.parametrize("argv, message", [
    (["run", "--speed_scale", "0"], "--speed_scale must be in (0, 1], got 0.0"),
    (["run", "--scripted", "--plan-only"], "--scripted runs the simulated scripted pull"),
    (["replay", "/nonexistent/run"], "run folder /nonexistent/run not found"),
])
def test_run_and_replay_options_are_checked_before_anything_is_built(capsys, tmp_path,
                                                                      argv, message):
    assert main(argv + ["--output", str(tmp_path / "o")]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_replay_of_a_folder_without_a_recording_names_the_file(capsys, tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    assert main(["replay", str(run), "--output", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "no recording in" in err and "recording.json not found" in err
