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
