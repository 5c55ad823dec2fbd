import json

import numpy as np
import pytest
import torch

from lmap_drake.plants.pepper import MakePepper, PepperShape
from lmap_drake.shape.config import ShapeConfig
from lmap_drake.shape.deepsdf import (DeepSDFDecoder, LoadDecoder, MissingWeightsError,
                                      ResolveWeightsPath, SaveDecoder)
from lmap_drake.shape.metrics import MeshChamferCm
from lmap_drake.shape.ssc import MakeFruitEstimate

WEIGHTS = ShapeConfig().weights_file


def test_committed_weights_are_small_and_load():
    path = ResolveWeightsPath(WEIGHTS)
    assert path.is_file(), f"{path} missing: run scripts/train_deepsdf.py"
    assert path.stat().st_size <= 5e6
    dec, mean, extra = LoadDecoder(WEIGHTS)
    assert mean.shape == (ShapeConfig().latent_size,)
    assert dec.latent_size == ShapeConfig().latent_size
    assert extra["train_latents"].shape[1] == dec.latent_size


@pytest.mark.parametrize("k", [0, 7])
def test_decoder_reproduces_a_training_shape(k):
    dec, mean, extra = LoadDecoder(WEIGHTS)
    summary = json.loads((ResolveWeightsPath(WEIGHTS).parent / "train_summary.json").read_text())
    params = dict(summary["shapes"][k])
    params["size"] = tuple(params["size"])
    gt = MakePepper(PepperShape(**params), subdivisions=4).mesh
    r_norm = summary["args"].get("normalize_radius", 0.0)
    if r_norm > 0:     # trained on size-normalised shapes (equal-volume radius)
        gt.apply_scale(r_norm / (3 * gt.volume / (4 * np.pi)) ** (1 / 3))
    z = extra["train_latents"][k]
    est = MakeFruitEstimate(dec, z, 1.0, np.eye(3), np.zeros(3), 0.002)
    cd = MeshChamferCm(est.vertices_W, est.faces, gt.vertices, gt.faces, 10000)
    assert cd < 0.12, cd  # cm
    # A different training latent gives a clearly different shape here.
    other = MakeFruitEstimate(dec, extra["train_latents"][k + 1], 1.0, np.eye(3), np.zeros(3),
                              0.003)
    assert MeshChamferCm(other.vertices_W, other.faces, gt.vertices, gt.faces, 10000) > cd
    # The SDF callable agrees with the mesh: vertices are on the zero level.
    assert np.abs(est.sdf_W(est.vertices_W[::50])).max() < 5e-4


def test_missing_weights_file_gives_a_clear_error(tmp_path):
    missing = tmp_path / "nope" / "decoder.pt"
    with pytest.raises(MissingWeightsError) as e:
        LoadDecoder(missing)
    msg = str(e.value)
    assert str(missing) in msg and "scripts/train_deepsdf.py" in msg


def test_hortimapping_style_checkpoint_loads(tmp_path):
    torch.manual_seed(0)
    ref = DeepSDFDecoder(latent_size=32, width=64, depth=8, latent_in=(4,), input_scale=1.0,
                         output_scale=1.0)
    state = {}
    for i, lin in enumerate(ref.layers):
        w = lin.weight.detach()
        g = w.norm(dim=1, keepdim=True) * 1.7
        v = w * 3.0  # weight = g * v / |v| = 1.7 w
        state[f"module.lin{i}.weight_g"] = g
        state[f"module.lin{i}.weight_v"] = v
        state[f"module.lin{i}.bias"] = lin.bias.detach().clone()
        with torch.no_grad():
            lin.weight.mul_(1.7)
    path = tmp_path / "latest.pth"
    torch.save({"epoch": 2000, "model_state_dict": state}, path)
    np.save(tmp_path / "mean.npy", np.full(32, 0.1, np.float32))
    dec, mean, _ = LoadDecoder(path, tmp_path / "mean.npy")
    assert (dec.width, dec.depth, dec.latent_in) == (64, 8, (4,))
    x = torch.rand(50, 3) * 0.1
    z = torch.full((32,), 0.1)
    torch.testing.assert_close(dec(z, x), ref(z, x))
    np.testing.assert_allclose(mean, 0.1)


def test_save_load_roundtrip(tmp_path):
    dec = DeepSDFDecoder(width=48, depth=4, latent_in=(2,))
    SaveDecoder(tmp_path / "d.pt", dec, np.arange(32, dtype=np.float32))
    dec2, mean, _ = LoadDecoder(tmp_path / "d.pt")
    x = torch.rand(10, 3)
    torch.testing.assert_close(dec2(torch.zeros(32), x), dec(torch.zeros(32), x))
    assert mean[5] == 5


def test_one_latent_for_all_points_gives_the_per_point_result():
    """A latent (C,) shared by every point (SSC's fits) is computed once per
    layer that takes it: values and gradients (points, latent, weights) are
    those of the same latent repeated per point."""
    torch.manual_seed(0)
    dec = DeepSDFDecoder(latent_size=8, width=16, depth=4, latent_in=(2,))
    x = (torch.rand(50, 3) - 0.5) * 0.1
    grads = []
    for shared in (True, False):
        z = torch.randn(8, requires_grad=True) if not grads else grads[0][0].detach().clone()
        z.requires_grad_(True)
        xi = x.clone().requires_grad_(True)
        dec.zero_grad()
        y = dec(z, xi) if shared else dec(z.unsqueeze(0).expand(len(x), -1), xi)
        (y ** 2).sum().backward()
        grads.append((z, y.detach(), xi.grad, z.grad, dec.layers[2].weight.grad.clone()))
    (z1, y1, gx1, gz1, gw1), (_, y2, gx2, gz2, gw2) = grads
    assert torch.allclose(y1, y2, atol=1e-7) and not torch.allclose(y1, torch.zeros_like(y1))
    for a, b in ((gx1, gx2), (gz1, gz2), (gw1, gw2)):
        assert torch.allclose(a, b, rtol=1e-5, atol=1e-8)
