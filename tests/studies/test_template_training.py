"""lmap_drake.studies.template_training (scripts/train_deepsdf.py) on a folder of
scans (kept tiny: 2 procedural shapes, 3 scans, a few steps)."""
import json
import subprocess
import sys
import time

import numpy as np
import pytest

from lmap_drake.errors import InputError
from lmap_drake.paths import REPO_ROOT
from lmap_drake.plants.pepper_meshes import MakeTestPepper
from lmap_drake.shape.deepsdf import LoadDecoder
from lmap_drake.studies.template_training import DeepSdfTrainingOptions, TrainDeepSdf

_SCRIPT = str(REPO_ROOT / "scripts" / "train_deepsdf.py")


def _scans(d, n=3, scale=1.0):
    d.mkdir(exist_ok=True)
    for i, kind in enumerate(["sculpted", "bent", "blob"][:n]):
        fruit, ped = MakeTestPepper(kind, np.random.default_rng(100 + i), True)
        fruit.apply_scale(scale)
        fruit.export(d / f"scan{i}.{['ply', 'stl', 'obj'][i]}")
        ped.export(d / f"scan{i}.peduncle.ply")       # stalks are skipped
    (d / "notes.txt").write_text("not a mesh")
    return d


def _train(**options):
    TrainDeepSdf(DeepSdfTrainingOptions(**options))


def test_train_on_scans_mixed_with_family(tmp_path):
    scans = _scans(tmp_path / "scans")
    out = tmp_path / "w"
    _train(meshes=str(scans), family="mixed", num_shapes=2, samples_per_shape=1024,
           steps=80, checkpoint_every=30, holdout_scans=1, holdout_family=1,
           holdout_iterations=20, out_dir=str(out))
    s = json.loads((out / "train_summary.json").read_text())
    assert len(s["scans_trained"]) == 2 and len(s["scans_held_out"]) == 1
    assert not set(s["scans_trained"]) & set(s["scans_held_out"])
    assert all(n.startswith("scan") for n in s["scans_trained"] + s["scans_held_out"])
    assert s["steps_done"] == 80 and "wide-1" in s["family"]
    for kind in ("scans", "family"):
        cd = s["heldout"][kind]["mean_chamfer_cm"]
        assert np.isfinite(cd) and 0 < cd < 5, (kind, cd)
    dec, mean, extra = LoadDecoder(out / "pepper_decoder.pt")
    assert extra["train_latents"].shape == (4, 32) and mean.shape == (32,)
    assert sum(n.startswith("scan") for n in extra["train_names"]) == 2
    # No checkpoint or temporary file is left behind.
    assert sorted(p.name for p in out.iterdir()) == [
        "mean_latent.npy", "pepper_decoder.pt", "train_summary.json"]
    # Fine-tuning from these weights keeps the architecture.
    out2 = tmp_path / "w2"
    _train(meshes=str(scans), num_shapes=1, samples_per_shape=512, steps=3, holdout_scans=0,
           holdout_family=0, init=str(out / "pepper_decoder.pt"), out_dir=str(out2))
    assert json.loads((out2 / "train_summary.json").read_text())["heldout"] == {}
    # With held-out shapes, a fine-tune reports the starting weights' error
    # on the same shapes next to its own.
    out3 = tmp_path / "w3"
    _train(meshes=str(scans), num_shapes=1, samples_per_shape=512, steps=3, holdout_scans=1,
           holdout_family=1, holdout_iterations=5, init=str(out / "pepper_decoder.pt"),
           out_dir=str(out3))
    h = json.loads((out3 / "train_summary.json").read_text())["heldout"]
    for kind in ("scans", "family"):
        assert set(h[kind]["init_per_shape_chamfer_cm"]) == set(h[kind]["per_shape_chamfer_cm"])
        assert np.isfinite(h[kind]["init_mean_chamfer_cm"])


def test_bad_scan_stops_before_training_naming_the_file(tmp_path):
    scans = _scans(tmp_path / "mm", n=1, scale=1000.0)        # a file in millimetres
    out = tmp_path / "w"
    with pytest.raises(InputError, match=r"scan0\.ply.*--mesh_scale: 0\.001"):
        _train(meshes=str(scans), num_shapes=2, steps=2, out_dir=str(out))
    assert not out.exists() or not any(out.iterdir())
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError, match="holds no .obj"):
        _train(meshes=str(empty), out_dir=str(out))


def test_checkpoints_and_an_interrupted_run_leave_no_finished_weights(tmp_path):
    seen = []
    rng = np.random.default_rng(0)
    pts = rng.uniform(-0.05, 0.05, (3, 64, 3)).astype(np.float32)
    sdf = (np.linalg.norm(pts, axis=2) - 0.03).astype(np.float32)
    from lmap_drake.shape import deepsdf
    deepsdf.TrainDecoder(pts, sdf, steps=12, shapes_per_batch=2, points_per_shape=16,
                         width=48, depth=8, log=lambda s: None,
                         checkpoint=lambda k, d, z: seen.append((k, z.shape)),
                         checkpoint_every=5)
    assert seen == [(5, (3, 32)), (10, (3, 32))]
    # A run killed while training: a checkpoint, no final weights.
    out = tmp_path / "w"
    proc = subprocess.Popen([sys.executable, _SCRIPT, "--num_shapes", "2",
                             "--samples_per_shape", "512", "--steps", "1000000",
                             "--checkpoint_every", "5", "--out_dir", str(out)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        t0 = time.time()
        while not (out / "pepper_decoder.checkpoint.pt").exists() and time.time() - t0 < 120:
            time.sleep(0.2)
    finally:
        proc.kill()
        proc.wait()
    assert (out / "pepper_decoder.checkpoint.pt").exists()
    assert not (out / "pepper_decoder.pt").exists()
    assert not (out / "train_summary.json").exists()
    dec, _, extra = LoadDecoder(out / "pepper_decoder.checkpoint.pt")
    assert extra["checkpoint_step"] % 5 == 0
