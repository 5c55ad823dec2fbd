"""Probes from issue 61 on data files and limits: no code runs from a
weights file, recording file names stay in their folder, sizes are bounded
before anything large is allocated, Drake-side settings are checked at load,
broken recordings and YAML give one line naming the file or key (exit 2),
and argparse errors are one line. Fast: loads and pure functions, no episode.
"""
import builtins
import errno
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from lmap_drake.cli import main
from lmap_drake.errors import EXIT_BAD_INPUT, EXIT_ERROR
from lmap_drake.paths import REPO_ROOT
from lmap_drake.scenario import LoadScenario, ScenarioError


def _run(capsys, *argv):
    code = main(list(argv))
    cap = capsys.readouterr()
    assert "Traceback" not in cap.err, cap.err
    return code, cap.err


def _one_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    return lines[0]


# ------------------------------------------------ 9. no code from a data file
class _Payload:
    """Unpickling this calls ``open(marker, 'w')``: it creates the marker."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (builtins.open, (self.marker, "w"))


def _evil_checkpoint(path: Path, marker: Path, key: str) -> Path:
    torch.save({key: _Payload(marker)}, path)
    return path


@pytest.mark.parametrize("key, field", [
    ("shape.weights_file", "model_state_dict"),
    ("perception.segnet_weights", "state_dict"),
])
def test_a_pickle_payload_in_weights_never_runs(capsys, tmp_path, key, field):
    marker = tmp_path / "PWNED"
    evil = _evil_checkpoint(tmp_path / "evil.pt", marker, field)
    section, name = key.split(".")
    extra = ", segmenter: segnet" if section == "perception" else ""
    out = tmp_path / "o"
    code, err = _run(capsys, "run", "--output", str(out), "--scenario_text",
                     f"{{{section}: {{{name}: '{evil}'{extra}}}}}")
    assert not marker.exists(), "the pickle's payload ran"
    assert code == EXIT_BAD_INPUT, err
    line = _one_line(err)
    assert str(evil) in line and key in line, line
    assert not out.exists()


def test_mean_latent_file_pickle_never_runs(tmp_path):
    from lmap_drake.shape.deepsdf import LoadDecoder, MissingWeightsError
    marker = tmp_path / "PWNED"
    hortimapping = tmp_path / "h.pt"
    torch.save({"model_state_dict": {"lin0.weight": torch.zeros(4, 7),
                                     "lin0.bias": torch.zeros(4),
                                     "lin1.weight": torch.zeros(1, 4),
                                     "lin1.bias": torch.zeros(1)}}, hortimapping)
    evil = _evil_checkpoint(tmp_path / "lat.pt", marker, "latent_codes")
    with pytest.raises(MissingWeightsError, match="shape.mean_latent_file"):
        LoadDecoder(hortimapping, evil)
    assert not marker.exists()
    npy = tmp_path / "lat.npy"
    np.save(npy, np.array([_Payload(marker)], dtype=object), allow_pickle=True)
    with pytest.raises(MissingWeightsError, match=str(npy)):
        LoadDecoder(hortimapping, npy)
    assert not marker.exists()


def test_the_shipped_weights_load_without_pickle():
    from lmap_drake.perception.segnet import LoadSegNet
    from lmap_drake.shape.deepsdf import LoadDecoder
    for f in ("models/deepsdf/pepper_decoder.pt", "models/segnet/segnet.pt"):
        torch.load(REPO_ROOT / f, map_location="cpu", weights_only=True)
    LoadDecoder(REPO_ROOT / "models/deepsdf/pepper_decoder.pt")
    LoadSegNet(REPO_ROOT / "models/segnet/segnet.pt")


def test_no_source_loads_pickles():
    """Every torch.load says weights_only=True; no np.load allows pickles."""
    bad = []
    for f in list((REPO_ROOT / "lmap_drake").rglob("*.py")) + list(
            (REPO_ROOT / "scripts").rglob("*.py")):
        for i, line in enumerate(f.read_text().splitlines(), 1):
            if ("torch.load(" in line and "weights_only=True" not in line) or \
                    "allow_pickle=True" in line or "weights_only=False" in line:
                bad.append(f"{f.relative_to(REPO_ROOT)}:{i}: {line.strip()}")
    assert not bad, bad


# ------------------------------------------- 10, 15, 20. broken recordings
W, H = 8, 6


def _recording(tmp_path) -> Path:
    """A run folder with a valid 1-view recording (8 x 6 px)."""
    from lmap_drake.perception.recording import CapturedView, SaveRecording
    run = tmp_path / "run"
    view = CapturedView(0, 0.0, 0.0, np.zeros((H, W, 4), np.uint8),
                        np.ones((H, W), np.float32), np.zeros((H, W), np.int16),
                        np.zeros(6), np.zeros(6), np.array([0.08, 0.0, np.nan]))
    cam = {"width": W, "height": H, "fx": 10.0, "fy": 10.0, "cx": 4.0, "cy": 3.0,
           "serial": "sim"}
    SaveRecording(run, [view], cam, np.eye(4), "simulation")
    return run


def _edit_manifest(run: Path, edit) -> Path:
    f = run / "recording" / "recording.json"
    m = json.loads(f.read_text())
    edit(m)
    f.write_text(json.dumps(m))
    return f


def _refused(run, *needles):
    from lmap_drake.perception.recording import LoadRecording, RecordingError
    with pytest.raises(RecordingError) as err:
        LoadRecording(run)
    msg = str(err.value)
    assert "\n" not in msg
    for n in needles:
        assert str(n) in msg, msg
    return msg


def test_the_valid_recording_loads(tmp_path):
    from lmap_drake.perception.recording import LoadRecording
    rec = LoadRecording(_recording(tmp_path))
    assert rec.views[0].rgb.shape == (H, W, 4) and rec.views[0].label.shape == (H, W)


@pytest.mark.parametrize("name", ["../../../etc/passwd", "/etc/passwd",
                                  "../../other/recording/view0_rgb.png", "sub/../../x.png"])
def test_recording_file_names_stay_in_the_folder(tmp_path, name):
    run = _recording(tmp_path)
    other = tmp_path / "other" / "recording"
    other.mkdir(parents=True)
    (other / "view0_rgb.png").write_bytes((run / "recording" / "view0_rgb.png").read_bytes())
    f = _edit_manifest(run, lambda m: m["views"][0].update(rgb=name))
    _refused(run, f, name, "outside the recording folder")


def test_a_symlink_out_of_the_recording_folder_is_refused(tmp_path):
    run = _recording(tmp_path)
    outside = tmp_path / "elsewhere.npy"
    np.save(outside, np.ones((H, W), np.float32))
    link = run / "recording" / "view0_depth.npy"
    link.unlink()
    link.symlink_to(outside)
    _refused(run, link, "outside the recording folder")


def test_truncated_png_names_the_file(tmp_path):
    run = _recording(tmp_path)
    png = run / "recording" / "view0_rgb.png"
    png.write_bytes(png.read_bytes()[:40])
    _refused(run, png)


def test_huge_png_is_refused_from_its_header(tmp_path):
    """A 20000 x 20000 PNG: the size is read from the header; nothing is
    decoded (the file itself is small)."""
    import struct
    import zlib
    run = _recording(tmp_path)
    png = run / "recording" / "view0_rgb.png"

    def chunk(kind, data):
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data) & 0xffffffff))
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(
        ">IIBBBBB", 20000, 20000, 8, 6, 0, 0, 0)) + chunk(b"IDAT", zlib.compress(b"\0" * 100))
        + chunk(b"IEND", b""))
    _refused(run, png, "20000 x 20000")


@pytest.mark.parametrize("content, needle", [
    (b"[1, 2, 3]", "JSON object"),
    (b"\xff\xfe\x00garbage", "not UTF-8"),
    (None, "not a file"),
])
def test_recording_json_that_is_not_an_object(tmp_path, content, needle):
    run = _recording(tmp_path)
    f = run / "recording" / "recording.json"
    f.unlink()
    if content is None:
        f.mkdir()
        (run / "recording" / "x").write_text("")
    else:
        f.write_bytes(content)
    _refused(run, f, needle)


@pytest.mark.parametrize("key, value", [("fx", 0.0), ("fy", -5.0), ("fx", None),
                                        ("width", 100000), ("height", 0), ("cx", "a")])
def test_recorded_intrinsics_are_checked(tmp_path, key, value):
    run = _recording(tmp_path)
    f = _edit_manifest(run, lambda m: m["camera"].update({key: value}))
    _refused(run, f, f"camera.{key}")


@pytest.mark.parametrize("content, needle", [
    (b"this is a PNG, not an array", "not a NumPy .npy"),
    ("pickle", "Python objects"),
    ("shape", "shape (3, 3)"),
])
def test_a_depth_file_that_is_not_a_depth_image_says_what_it_is(tmp_path, content, needle):
    run = _recording(tmp_path)
    depth = run / "recording" / "view0_depth.npy"
    if content == "pickle":
        np.save(depth, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    elif content == "shape":
        np.save(depth, np.ones((3, 3), np.float32))
    else:
        depth.write_bytes(content)
    msg = _refused(run, depth, needle)
    assert "pickled data" not in msg


def test_replay_on_a_file_says_it_is_not_a_run_folder(capsys, tmp_path):
    f = tmp_path / "episode.json"
    f.write_text("{}")
    code, err = _run(capsys, "replay", str(f), "--output", str(tmp_path / "o"))
    assert code == EXIT_BAD_INPUT and "not a run folder" in _one_line(err) and str(f) in err
    from lmap_drake.perception.recording import LoadRecording, RecordingError
    with pytest.raises(RecordingError, match="not a run folder"):
        LoadRecording(f)


@pytest.mark.parametrize("content", ["{not json", "[1]", '{"chosen_action": 3}'])
def test_replay_checks_the_runs_plan_before_planning(capsys, tmp_path, monkeypatch, content):
    import lmap_drake.episode.replay as replay
    run = _recording(tmp_path)
    (run / "plan.json").write_text(content)
    (run / "scenario.yaml").write_text("{}")
    monkeypatch.setattr(replay.EpisodeResources, "Make",
                        lambda *a, **k: pytest.fail("planning started"))
    out = tmp_path / "o"
    code, err = _run(capsys, "replay", str(run), "--output", str(out))
    assert code == EXIT_BAD_INPUT and str(run / "plan.json") in _one_line(err), err
    assert not out.exists()
    with pytest.raises(replay.RecordingError, match="plan.json"):
        replay.ReplayRun(run, tmp_path / "o2")


# ------------------------------------------------------------- 12. size limits
def test_a_huge_camera_is_refused_at_load():
    from lmap_drake.limits import MAX_IMAGE_SIDE
    with pytest.raises(ScenarioError, match=rf"cameras.camera0 .*at most {MAX_IMAGE_SIDE}"):
        LoadScenario(scenario_text="{cameras: {camera0: {width: 100000, height: 100000}}}")


def test_scenario_file_from_dev_zero_is_bounded(capsys, tmp_path):
    code, err = _run(capsys, "run", "--scenario_file", "/dev/zero",
                     "--output", str(tmp_path / "o"))
    assert code == EXIT_BAD_INPUT and "/dev/zero" in _one_line(err) and "limit" in err


def test_scenario_file_from_an_endless_fifo_is_bounded(tmp_path):
    import threading
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)

    def writer():
        try:
            with open(fifo, "wb") as f:
                while True:
                    f.write(b"# comment line\n" * 4096)
        except (BrokenPipeError, OSError):
            pass
    t = threading.Thread(target=writer, daemon=True)
    t.start()
    with pytest.raises(ScenarioError, match=f"{fifo}.*larger than the limit"):
        LoadScenario(filename=fifo)
    t.join(5)


def test_big_scenario_file_and_text_are_refused(tmp_path):
    from lmap_drake.limits import MAX_SCENARIO_BYTES
    f = tmp_path / "big.yaml"
    f.write_text("Defaults: {}\n" + "# padding\n" * (MAX_SCENARIO_BYTES // 10 + 1))
    with pytest.raises(ScenarioError, match=f"{f}.*limit of {MAX_SCENARIO_BYTES} bytes"):
        LoadScenario(filename=f)
    with pytest.raises(ScenarioError, match="--scenario_text is larger than the limit"):
        LoadScenario(scenario_text="{random_seed: 1}" + " " * MAX_SCENARIO_BYTES)


def _stl_header(path: Path, faces: int) -> Path:
    path.write_bytes(b"\0" * 80 + faces.to_bytes(4, "little") + b"\0" * 50)
    return path


def _ply_header(path: Path, faces: int) -> Path:
    path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 3\n"
                     b"property float x\nproperty float y\nproperty float z\n"
                     b"element face %d\nproperty list uchar int vertex_indices\nend_header\n"
                     % faces)
    return path


@pytest.mark.parametrize("make", [_stl_header, _ply_header])
def test_mesh_face_count_is_read_from_the_header_before_loading(tmp_path, monkeypatch, make):
    import lmap_drake.plants.fruit_mesh as fm
    monkeypatch.setattr(fm.trimesh, "load", lambda *a, **k: pytest.fail("mesh loaded"))
    f = make(tmp_path / f"big{'.stl' if make is _stl_header else '.ply'}", 5_200_000)
    with pytest.raises(fm.FruitMeshError, match=f"plant_scene.fruit.mesh_file {f} declares "
                                                f"5200000 faces"):
        fm.LoadFruitMesh(str(f))


def test_obj_face_count_is_bounded(tmp_path, monkeypatch):
    import trimesh

    import lmap_drake.plants.fruit_mesh as fm
    f = tmp_path / "sphere.obj"
    trimesh.creation.icosphere(subdivisions=3, radius=0.035).export(f)
    fm.LoadFruitMesh(str(f))
    monkeypatch.setattr(fm, "MAX_MESH_FACES", 100)
    fm._Cached.cache_clear()
    with pytest.raises(fm.FruitMeshError, match="declares 1280 faces, more than the limit of 100"):
        fm.LoadFruitMesh(str(f))


def test_eval_scenarios_is_bounded(capsys, tmp_path):
    code, err = _run(capsys, "eval", "--scenarios", "100000000", "--output",
                     str(tmp_path / "o"))
    assert code == EXIT_BAD_INPUT and "--scenarios must be in [1, 10000]" in _one_line(err)
    assert not (tmp_path / "o").exists()


# ---------------------------------------------- 13. Drake-side settings at load
@pytest.mark.parametrize("text, key", [
    ("{plant_config: {time_step: .nan}}", "plant_config.time_step"),
    ("{plant_config: {time_step: -0.01}}", "plant_config.time_step"),
    ("{plant_config: {contact_model: magic}}", "plant_config.contact_model"),
    ("{plant_config: {discrete_contact_approximation: x}}",
     "plant_config.discrete_contact_approximation"),
    ("{cameras: {camera0: {X_PB: {base_frame: nowhere}}}}", "cameras.camera0.X_PB.base_frame"),
    ("{cameras: {camera0: {renderer_class: RenderEngineMagic}}}",
     "cameras.camera0.renderer_class"),
    ("{lights: [{type: laser}]}", "lights[0].type"),
    ("{lights: [{type: point, frame: moon}]}", "lights[0].frame"),
    ("{lights: [{type: spot, cone_angle: 120}]}", "lights[0].cone_angle"),
    ("{simulator_config: {max_step_size: -1}}", "simulator_config.max_step_size"),
    ("{simulator_config: {integration_scheme: magic}}", "simulator_config.integration_scheme"),
    ("{simulator_config: {accuracy: 0}}", "simulator_config.accuracy"),
    ("{scene_graph_config: {default_proximity_properties: {compliance_type: jelly}}}",
     "scene_graph_config.default_proximity_properties.compliance_type"),
])
def test_drake_settings_are_checked_at_load(text, key):
    with pytest.raises(ScenarioError) as err:
        LoadScenario(scenario_text=text)
    assert str(err.value).startswith(key + " ") and "--scenario_text" in str(err.value)


def test_the_shipped_scenarios_pass_the_drake_checks():
    from lmap_drake.scenario import RawYaml
    for name in ("default.yaml", "suite.yaml", "multi_suite.yaml"):
        f = REPO_ROOT / "diagrams" / name
        for scenario in RawYaml(f.read_text()):
            if not scenario.startswith("_"):
                LoadScenario(filename=f, scenario_name=scenario)


# ------------------------------------------------ 14, 20. hostile YAML
_BOMB = ("{planner: {distances: [&b [1,1,1,1,1,1,1,1,1], &c [*b,*b,*b,*b,*b,*b,*b,*b,*b], "
         "&d [*c,*c,*c,*c,*c,*c,*c,*c,*c], &e [*d,*d,*d,*d,*d,*d,*d,*d,*d], "
         "&f [*e,*e,*e,*e,*e,*e,*e,*e,*e], &g [*f,*f,*f,*f,*f,*f,*f,*f,*f]]}}")


@pytest.mark.parametrize("text, needle", [
    ("{plant_scene: " + "[" * 200 + "]" * 200 + "}", "plant_scene[0][0]"),
    ("[" * 100000 + "]" * 100000, "--scenario_text"),
    ("{random_seed: 18446744073709551616}", "random_seed = 18446744073709551616"),
    ("{random_seed: -99999999999999999999999}", "random_seed"),
    ("{planner: {num_grasps: 0x1FFFFFFFFFFFFFFFF}}", "planner.num_grasps"),
    (_BOMB, "planner.distances"),
])
def test_hostile_yaml_is_one_line_naming_the_key(capsys, tmp_path, text, needle):
    with pytest.raises(ScenarioError, match=None) as err:
        LoadScenario(scenario_text=text)
    assert needle in str(err.value) and "\n" not in str(err.value)
    code, msg = _run(capsys, "run", "--scenario_text", text, "--output", str(tmp_path / "o"))
    assert code == EXIT_BAD_INPUT and needle in _one_line(msg)


def test_hostile_yaml_in_a_file_names_the_file(tmp_path):
    f = tmp_path / "s.yaml"
    f.write_text("Defaults:\n  random_seed: 18446744073709551616\n")
    with pytest.raises(ScenarioError, match=f"{f}: Defaults.random_seed = 1844"):
        LoadScenario(filename=f, scenario_name="Defaults")


def test_an_out_of_range_colour_names_its_key():
    with pytest.raises(ScenarioError) as err:
        LoadScenario(scenario_text="{plant_scene: {leaf: {color: {rgba: [2.0, 0.5, 0.2]}}}}")
    assert "plant_scene.leaf.color = " in str(err.value), err.value
    with pytest.raises(ScenarioError, match="plant_scene.fruit.color = "):
        LoadScenario(scenario_text="{plant_scene: {fruit: {color: [0.2, 0.5, 0.2]}}}")
    LoadScenario(scenario_text="{plant_scene: {leaf: {color: {rgba: [0.2, 0.5, 0.2]}}}}")


# ------------------------------------------------------------------ 19. disk full
@pytest.fixture
def tiny_disk(tmp_path):
    """A 64 KB tmpfs (needs root), else None."""
    d = tmp_path / "tiny"
    d.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(d)],
                       capture_output=True)
    if r.returncode != 0:
        yield None
        return
    try:
        yield d
    finally:
        subprocess.run(["umount", str(d)], capture_output=True)


def test_disk_full_names_the_file_being_written(capsys, tmp_path, monkeypatch, tiny_disk):
    """ENOSPC is exit 1 (a device failure, not bad input), one line naming the
    file being written; the output folder is absent."""
    import lmap_drake.episode as E

    def snapshot(scenario, out, hardware=False, progress=print):
        with open(Path(out) / "rgb.png", "wb") as f:
            if tiny_disk is None:        # not root: the write fails as a full disk would
                raise OSError(errno.ENOSPC, "No space left on device")
            for _ in range(64):
                f.write(os.urandom(4096))
                f.flush()
        return ["rgb.png"]
    monkeypatch.setattr(E, "RunStationSnapshot", snapshot)
    out = (tiny_disk or tmp_path) / "o"
    code, err = _run(capsys, "run", "--output", str(out), "--scenario_text",
                     "{plant_scene: {kind: placeholder}, simulation_duration: 0.05}")
    line = _one_line(err)
    assert code == EXIT_ERROR and "No space left on device" in line, line
    assert "rgb.png" in line and str(out.parent) in line, line
    assert not out.exists() and not list(out.parent.glob(".o.*"))


# ------------------------------------------------------- 24. one-line usage errors
@pytest.mark.parametrize("argv, needle", [
    (["run", "--speed_scale", "fast"], "argument --speed_scale: invalid float value"),
    (["frobnicate"], "invalid choice: 'frobnicate'"),
    (["eval", "--workers", "many"], "argument --workers: invalid int value"),
    (["replay"], "the following arguments are required: run_dir"),
    (["run", "--no_such_flag"], "unrecognized arguments: --no_such_flag"),
])
def test_argparse_errors_are_one_line(capsys, argv, needle):
    code, err = _run(capsys, *argv)
    line = _one_line(err)
    assert code == EXIT_BAD_INPUT and needle in line and "usage:" not in err, err


def test_script_argparse_errors_are_one_line():
    r = subprocess.run([sys.executable, str(REPO_ROOT / "scripts" / "make_suite.py"),
                        "--no_such_flag"], capture_output=True, text=True, timeout=120,
                       env={**os.environ, "PYTHONPATH": str(REPO_ROOT)})
    assert r.returncode == EXIT_BAD_INPUT and "usage:" not in r.stderr
    assert "unrecognized arguments: --no_such_flag" in _one_line(r.stderr)


def test_sweep_file_read_is_bounded(tmp_path):
    from lmap_drake.evaluation.sweep import LoadSweep, SweepError
    f = tmp_path / "sweep.yaml"
    f.write_text("planner.energy_weight: [0, 1]\n" + "#\n" * 600_000)
    with pytest.raises(SweepError, match=f"{f} is larger than the limit"):
        LoadSweep(f)
