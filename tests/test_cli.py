"""``lmap-drake run`` end to end on the default scenario."""
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


def test_run_hardware_not_available(tmp_path, capsys):
    assert main(["run", "--hardware", "--output", str(tmp_path)]) == 1
    assert "hardware station" in capsys.readouterr().err
