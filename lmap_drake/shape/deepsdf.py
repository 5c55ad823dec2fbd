"""DeepSDF pepper template (Park et al. 2019; the HortiMapping / Pan et al.
2023 layout): an MLP ``D(x, z)`` of a query point ``x`` in the canonical
pepper frame O (metres, centroid at the origin, peduncle on +z) and a latent
shape code ``z`` (C = 32), returning the signed distance in metres
(negative inside).

Architecture: ``depth`` hidden layers of ``width`` units with ReLU, the
input ``[z, x * input_scale]`` re-injected before layer ``latent_in``
(default 4), a final linear layer and tanh, times ``output_scale``.
The project's trained template (``models/deepsdf/pepper_decoder.pt``,
written by ``scripts/train_deepsdf.py``) uses 8 x 128, input_scale 1/0.08
(the canonical cube of radius 0.08 m maps to [-1, 1]) and output_scale 0.1
(m). A HortiMapping-style checkpoint (``model_state_dict`` with
``module.linN.weight_g / weight_v / bias``, e.g. 8 x 512) loads too: weight
norm is folded into plain weights, scales are 1 (metric in, metric out).
"""
from __future__ import annotations

import json
import pickle
import re
import time
from pathlib import Path

import numpy as np
import torch

# The decoder runs on small batches (hundreds of points, 8 x 128 layers):
# one intra-op thread is ~25x faster than two on a loaded 2-core machine
# (measured: SSC 29 s -> 1.1 s). Override with LMAP_TORCH_THREADS.
torch.set_num_threads(int(__import__("os").environ.get("LMAP_TORCH_THREADS", "1")))
from torch import nn

from lmap_drake.errors import WeightsError
from lmap_drake.paths import REPO_ROOT

FORMAT = "lmap_drake.deepsdf.v1"
CUBE_RADIUS = 0.08      # m, half-side of the canonical training cube
CLAMP = 0.01            # m, SDF clamp distance used in training (DeepSDF's delta)
TRAIN_SCRIPT = "scripts/train_deepsdf.py"


class MissingWeightsError(WeightsError):
    """The decoder weights file does not exist, or cannot be read as a
    DeepSDF checkpoint (the message names the file)."""


class DeepSDFDecoder(nn.Module):
    """``forward(z, x) -> sdf``: z (C,) or (N, C), x (N, 3) in frame O
    (m); returns (N,) signed distances (m)."""

    def __init__(self, latent_size: int = 32, width: int = 128, depth: int = 8,
                 latent_in: tuple[int, ...] = (4,), input_scale: float = 1.0 / CUBE_RADIUS,
                 output_scale: float = 0.1):
        super().__init__()
        self.latent_size, self.width, self.depth = latent_size, width, depth
        self.latent_in = tuple(int(i) for i in latent_in)
        self.input_scale, self.output_scale = float(input_scale), float(output_scale)
        d_in = latent_size + 3
        dims = [d_in] + [width] * depth + [1]
        layers = []
        for l in range(depth + 1):
            out = dims[l + 1] - (d_in if (l + 1) in self.latent_in else 0)
            layers.append(nn.Linear(dims[l], out))
        self.layers = nn.ModuleList(layers)

    def config(self) -> dict:
        return dict(latent_size=self.latent_size, width=self.width, depth=self.depth,
                    latent_in=list(self.latent_in), input_scale=self.input_scale,
                    output_scale=self.output_scale)

    def forward(self, z: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        if z.dim() == 1 and 0 not in self.latent_in:
            return self._ForwardOneLatent(z, x)
        if z.dim() == 1:
            z = z.unsqueeze(0).expand(x.shape[0], -1)
        inp = torch.cat([z, x * self.input_scale], 1)
        h = inp
        for l, lin in enumerate(self.layers):
            if l in self.latent_in:
                h = torch.cat([h, inp], 1)
            h = lin(h)
            if l < self.depth:
                h = torch.relu(h)
        return torch.tanh(h[:, 0]) * self.output_scale

    def _ForwardOneLatent(self, z: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """``forward`` for one latent z (C,) shared by every point: the
        latent's share of the layers that take it (the first and
        ``latent_in``) is one matrix-vector product instead of one per point
        (the same sums; at 8 x 128 about 7 % fewer flops, and no (N, C)
        copy of z)."""
        C = self.latent_size
        xs = x * self.input_scale
        for l, lin in enumerate(self.layers):
            W, b = lin.weight, lin.bias
            if l == 0:                       # input [z, xs]
                h = torch.addmm(b + W[:, :C] @ z, xs, W[:, C:].t())
            elif l in self.latent_in:        # input [h, z, xs]
                n = h.shape[1]
                h = torch.addmm(b + W[:, n:n + C] @ z, torch.cat([h, xs], 1),
                                torch.cat([W[:, :n], W[:, n + C:]], 1).t())
            else:
                h = lin(h)
            if l < self.depth:
                h = torch.relu(h)
        return torch.tanh(h[:, 0]) * self.output_scale

    @torch.no_grad()
    def sdf_numpy(self, z, x: np.ndarray, batch: int = 65536) -> np.ndarray:
        """Numpy convenience: (N,3) points in O (m) -> (N,) SDF (m)."""
        zt = torch.as_tensor(np.asarray(z), dtype=torch.float32)
        out = []
        for i in range(0, len(x), batch):
            xt = torch.as_tensor(np.asarray(x[i:i + batch]), dtype=torch.float32)
            out.append(self(zt, xt).numpy())
        return np.concatenate(out) if out else np.zeros(0)


def _box_sdf(x: torch.Tensor, r: float) -> torch.Tensor:
    q = x.abs() - r
    outside = torch.clamp(q, min=0).norm(dim=1)
    inside = torch.clamp(q.max(dim=1).values, max=0)
    return outside + inside


def DecoderSdf(decoder: DeepSDFDecoder, z: torch.Tensor, x_O: torch.Tensor) -> torch.Tensor:
    """Decoder SDF in O (m), bounded below by the training cube's SDF."""
    return torch.maximum(decoder(z, x_O), _box_sdf(x_O, CUBE_RADIUS))


def ResolveWeightsPath(weights_file: str | Path) -> Path:
    """Relative paths are relative to the repository root."""
    p = Path(weights_file)
    return p if p.is_absolute() else REPO_ROOT / p


def SaveDecoder(path: str | Path, decoder: DeepSDFDecoder, mean_latent: np.ndarray,
                extra: dict | None = None) -> None:
    """Writes our checkpoint format (float32 state dict + config + mean latent)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().float().clone() for k, v in decoder.state_dict().items()}
    torch.save({"format": FORMAT, "config": decoder.config(), "model_state_dict": state,
                "mean_latent": torch.as_tensor(np.asarray(mean_latent), dtype=torch.float32),
                **(extra or {})}, path)


def _from_hortimapping(state: dict) -> tuple[DeepSDFDecoder, dict]:
    """Builds a decoder from a DeepSDF/HortiMapping ``model_state_dict``
    (keys ``[module.]linN.weight_g|weight_v|weight|bias``)."""
    layers: dict[int, dict] = {}
    for k, v in state.items():
        m = re.match(r"(?:module\.)?lin(\d+)\.(weight_g|weight_v|weight|bias)$", k)
        if m:
            layers.setdefault(int(m.group(1)), {})[m.group(2)] = v.float()
    if not layers:
        raise ValueError("no linN.* weights in the checkpoint")
    weights = []
    for i in sorted(layers):
        d = layers[i]
        if "weight" in d:
            w = d["weight"]
        else:
            v, g = d["weight_v"], d["weight_g"]
            w = g.reshape(-1, 1) * v / v.norm(dim=1, keepdim=True)
        weights.append((w, d["bias"]))
    d_in = weights[0][0].shape[1]
    width = weights[0][0].shape[0]
    depth = len(weights) - 1
    latent_in = tuple(l for l in range(1, depth + 1) if weights[l - 1][0].shape[0] == width - d_in)
    dec = DeepSDFDecoder(d_in - 3, width, depth, latent_in, 1.0, 1.0)
    with torch.no_grad():
        for lin, (w, b) in zip(dec.layers, weights):
            lin.weight.copy_(w)
            lin.bias.copy_(b)
    return dec, {"source": "hortimapping"}


def _TensorLoad(path: Path, key: str):
    """``torch.load`` of tensors, numbers, strings, lists and dicts only
    (``weights_only=True``): a file holding any other pickled object is
    refused, never executed (``MissingWeightsError`` naming the file and
    ``key``)."""
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as err:
        first = " ".join(str(err).split("\n\n")[-1].split())[:160]
        raise MissingWeightsError(
            f"refusing {path} ({key}): it holds pickled Python objects other than tensors, "
            f"which are never loaded (weights_only=True; {first})") from None


def _DecoderFromFile(path: Path, mean_latent_file) -> tuple:
    ckpt = _TensorLoad(path, "shape.weights_file")
    if isinstance(ckpt, dict) and ckpt.get("format") == FORMAT:
        cfg = ckpt["config"]
        dec = DeepSDFDecoder(cfg["latent_size"], cfg["width"], cfg["depth"],
                             tuple(cfg["latent_in"]), cfg["input_scale"], cfg["output_scale"])
        dec.load_state_dict(ckpt["model_state_dict"])
        mean = ckpt["mean_latent"].numpy().astype(np.float32)
        extra = {k: v for k, v in ckpt.items() if k not in ("model_state_dict",)}
    else:
        state = ckpt.get("model_state_dict", ckpt) if isinstance(ckpt, dict) else ckpt
        dec, extra = _from_hortimapping(state)
        mean = np.zeros(dec.latent_size, np.float32)
        if mean_latent_file is not None:
            mp = ResolveWeightsPath(mean_latent_file)
            if mp.suffix == ".npy":
                mean = np.load(mp, allow_pickle=False).astype(np.float32).reshape(-1)
            else:
                lat = _TensorLoad(mp, "shape.mean_latent_file")
                if isinstance(lat, dict):
                    lat = lat.get("latent_codes", {}).get("weight", lat)
                mean = torch.as_tensor(lat).float().reshape(-1, dec.latent_size).mean(0).numpy()
    return dec, mean, extra


def LoadDecoder(weights_file: str | Path, mean_latent_file: str | Path | None = None
                ) -> tuple[DeepSDFDecoder, np.ndarray, dict]:
    """Loads ``(decoder, mean_latent (C,), checkpoint_extra)``. Accepts this
    project's format and HortiMapping-style checkpoints (whose mean latent,
    if any, comes from ``mean_latent_file`` (.npy or .pt) or is zero).
    A missing file raises ``MissingWeightsError`` naming the path and the
    script that writes it."""
    path = ResolveWeightsPath(weights_file)
    if not path.is_file():
        raise MissingWeightsError(
            f"DeepSDF weights not found: {path}. Train them with "
            f"`.venv/bin/python {TRAIN_SCRIPT}` (writes models/deepsdf/pepper_decoder.pt) "
            f"or set shape.weights_file to a HortiMapping-style checkpoint.")
    try:
        dec, mean, extra = _DecoderFromFile(path, mean_latent_file)
    except MissingWeightsError:
        raise
    except Exception as err:  # noqa: BLE001 - garbage, truncated, wrong format
        raise MissingWeightsError(
            f"cannot read DeepSDF weights {path}"
            + (f" (mean latent file {mean_latent_file})" if mean_latent_file else "")
            + f": {type(err).__name__}: "
            f"{' '.join(str(err).split())[:200]} (expected a checkpoint written by "
            f"{TRAIN_SCRIPT} or a HortiMapping-style one; see shape.weights_file)") from None
    dec.eval()
    for p in dec.parameters():
        p.requires_grad_(False)
    return dec, mean, extra


# --------------------------------------------------------------------------
# Training data and auto-decoder training


def MeshSdfSamples(vertices: np.ndarray, faces: np.ndarray, n: int,
                   rng: np.random.Generator, near_fraction: float = 0.8,
                   sigmas=(0.0025, 0.01)) -> tuple[np.ndarray, np.ndarray]:
    """SDF samples of a watertight mesh in its frame (m): ``near_fraction``
    of them are surface points perturbed by Gaussian noise (half with each
    sigma), the rest uniform in the canonical cube (radius 0.08 m).
    Returns points (n,3) float32 and signed distances (n,) float32."""
    import open3d as o3d
    import trimesh
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    n_near = int(n * near_fraction)
    surf, _ = trimesh.sample.sample_surface(mesh, n_near, seed=int(rng.integers(2**31)))
    sig = np.where(np.arange(n_near) % 2 == 0, sigmas[0], sigmas[1])[:, None]
    near = surf + rng.normal(size=surf.shape) * sig
    uni = rng.uniform(-CUBE_RADIUS, CUBE_RADIUS, size=(n - n_near, 3))
    pts = np.concatenate([near, uni]).astype(np.float32)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh(
        o3d.core.Tensor(np.asarray(vertices, np.float32)),
        o3d.core.Tensor(np.asarray(faces, np.int32))))
    sdf = scene.compute_signed_distance(o3d.core.Tensor(pts)).numpy().astype(np.float32)
    return pts, sdf


def TrainDecoder(points: np.ndarray, sdf: np.ndarray, *, latent_size=32, width=128, depth=8,
                 steps=3000, shapes_per_batch=32, points_per_shape=256, lr=1e-3,
                 lr_latent=1e-3, code_reg=1e-4, code_init_std=0.01, seed=0, log=print,
                 log_every=100, time_limit_s: float | None = None,
                 init_decoder: "DeepSDFDecoder | None" = None,
                 shape_weights: np.ndarray | None = None, on_step=None,
                 checkpoint=None, checkpoint_every: int = 500):
    """Auto-decoder training (DeepSDF): per-shape latents optimised jointly
    with the decoder. ``points`` (S, P, 3), ``sdf`` (S, P) in metres. Loss:
    L1 between clamped (``CLAMP``) predicted and true SDF divided by
    ``CLAMP``, plus ``code_reg * ||z||^2`` (mean over the batch).

    ``init_decoder``: start from a copy of these weights (fine-tuning; its
    architecture wins over ``latent_size``/``width``/``depth``).
    ``shape_weights`` (S,): relative probability of drawing each shape into
    a batch (e.g. scans drawn more often than the many procedural shapes);
    uniform when None. ``on_step(step)`` is called after every step (a
    progress bar); ``checkpoint(step, decoder, latents)`` every
    ``checkpoint_every`` steps.
    Returns ``(decoder, latents (S, C), history list)``."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    S, P = sdf.shape
    if init_decoder is not None:
        import copy
        dec = copy.deepcopy(init_decoder)
        for prm in dec.parameters():
            prm.requires_grad_(True)
        dec.train()
        latent_size = dec.latent_size
    else:
        dec = DeepSDFDecoder(latent_size, width, depth)
    prob = None
    if shape_weights is not None:
        prob = np.asarray(shape_weights, float)
        if prob.shape != (S,) or np.any(prob < 0) or prob.sum() <= 0:
            raise ValueError(f"shape_weights must be {S} non-negative numbers, not all zero")
        prob = prob / prob.sum()
    codes = nn.Embedding(S, latent_size)
    nn.init.normal_(codes.weight, 0.0, code_init_std)
    opt = torch.optim.Adam([{"params": dec.parameters(), "lr": lr},
                            {"params": codes.parameters(), "lr": lr_latent}])
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps, eta_min=0.05 * lr)
    pts_t = torch.as_tensor(points, dtype=torch.float32)
    sdf_t = torch.as_tensor(sdf, dtype=torch.float32).clamp(-CLAMP, CLAMP)
    hist, t0, run = [], time.time(), []
    for step in range(steps):
        ids = torch.as_tensor(rng.choice(S, min(shapes_per_batch, S), replace=False)
                              if prob is None else
                              rng.choice(S, min(shapes_per_batch, int((prob > 0).sum())),
                                         replace=False, p=prob))
        pidx = torch.as_tensor(rng.integers(0, P, size=(len(ids), points_per_shape)))
        x = pts_t[ids[:, None], pidx].reshape(-1, 3)
        y = sdf_t[ids[:, None], pidx].reshape(-1)
        z = codes(ids)
        zz = z.repeat_interleave(points_per_shape, 0)
        pred = dec(zz, x).clamp(-CLAMP, CLAMP)
        l_sdf = (pred - y).abs().mean() / CLAMP
        l_reg = code_reg * (z ** 2).sum(1).mean()
        loss = l_sdf + l_reg
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        run.append(l_sdf.item())
        if on_step is not None:
            on_step(step + 1)
        if checkpoint is not None and (step + 1) % checkpoint_every == 0 and step + 1 < steps:
            checkpoint(step + 1, dec, codes.weight.detach().numpy().copy())
        if (step + 1) % log_every == 0 or step == steps - 1:
            rec = dict(step=step + 1, l1_over_clamp=float(np.mean(run)),
                       l1_mm=float(np.mean(run)) * CLAMP * 1000,
                       code_norm=float(codes.weight.detach().norm(dim=1).mean()),
                       seconds=round(time.time() - t0, 1))
            hist.append(rec)
            run = []
            log(f"step {rec['step']:5d}/{steps}  L1 {rec['l1_mm']:.3f} mm  "
                f"|z| {rec['code_norm']:.3f}  {rec['seconds']:.0f} s")
        if time_limit_s is not None and time.time() - t0 > time_limit_s:
            log(f"time limit {time_limit_s} s reached at step {step + 1}")
            break
    dec.eval()
    for prm in dec.parameters():
        prm.requires_grad_(False)
    return dec, codes.weight.detach().numpy().copy(), hist


def FitLatent(decoder: DeepSDFDecoder, points: np.ndarray, sdf: np.ndarray,
              z0: np.ndarray, iterations: int = 400, lr: float = 5e-3,
              code_reg: float = 1e-4, batch: int = 4096, seed: int = 0) -> np.ndarray:
    """The latent (C,) whose decoder surface best fits SDF samples of one
    shape in frame O (the DeepSDF inference: the decoder frozen, Adam on z
    from ``z0``, clamped L1 plus ``code_reg * ||z||^2``)."""
    rng = np.random.default_rng(seed)
    z = torch.tensor(np.asarray(z0, np.float32), requires_grad=True)
    opt = torch.optim.Adam([z], lr=lr)
    pts = torch.as_tensor(points, dtype=torch.float32)
    y = torch.as_tensor(sdf, dtype=torch.float32).clamp(-CLAMP, CLAMP)
    for _ in range(iterations):
        i = torch.as_tensor(rng.integers(0, len(pts), min(batch, len(pts))))
        pred = decoder(z, pts[i]).clamp(-CLAMP, CLAMP)
        loss = (pred - y[i]).abs().mean() / CLAMP + code_reg * (z ** 2).sum()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return z.detach().numpy().copy()


def LoadTrainingSummary(weights_file: str | Path) -> dict:
    """The JSON summary next to the weights (``train_summary.json``)."""
    p = ResolveWeightsPath(weights_file).parent / "train_summary.json"
    return json.loads(p.read_text())
