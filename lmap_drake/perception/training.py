"""Training of the RGB-D segmentation network (``lmap_drake/perception/segnet.py``)
on the randomised renders of ``scripts/make_segnet_data.py``.

    python scripts/make_segnet_data.py --out out/segnet_data --count 520 --seed 10000
    python scripts/train_segnet.py --data out/segnet_data --out models/segnet/segnet.pt

Random 128 x 128 crops (centred on fruit pixels 45 % of the time, on other
plant pixels 25 %, on the robot and other non-plant returns 30 %; in a
sample with a leaf boundary target 35 % fruit, 15 % on the boundary band,
25 % plant, 25 % robot and other returns), horizontal flips and
colour jitter (``ColorJitter``: gain, per-channel white balance, hue shifts,
blur, pixel noise); cross-entropy with the fruit and branch classes weighted
2x; Adam with a cosine learning-rate decay. A tenth of the samples (every
10th seed) is held out and reported as per-class IoU (green and other fruit
separately) in the weights file's ``meta`` and in ``OUT.json``. About 15 min
on 2 cores for the defaults.
"""
from __future__ import annotations

import dataclasses as dc
import json
import math
import time
from pathlib import Path

import numpy as np
import torch
from scipy import ndimage
from tqdm import tqdm

from lmap_drake.errors import InputError
from lmap_drake.labels import LEAF
from lmap_drake.perception.leaf_boundaries import BandCounts, BandPrecisionRecall
from lmap_drake.perception.segnet import NUM_CLASSES, LoadSegNet, PredictLogits, SaveSegNet, SegNet

CROP = 128
IGNORE = 255            # a boundary target pixel left out of the loss
# The boundary head's loss: binary cross-entropy on the truth leaf pixels
# (the only ones perception cuts), the band's pixels weighted
# BOUNDARY_POS_WEIGHT (about 4 % of leaf pixels lie on a band in a
# greenhouse view), added to the class loss with BOUNDARY_WEIGHT.
BOUNDARY_WEIGHT = 0.5
BOUNDARY_POS_WEIGHT = 3.0


@dc.dataclass
class SegNetTrainingOptions:
    """The training's settings (the flags of ``scripts/train_segnet.py``)."""
    data: str = ""                   # folder of make_segnet_data.py samples
    out: str = "models/segnet/segnet.pt"
    steps: int = 1800
    batch: int = 12
    lr: float = 3e-3
    threads: int = 2
    seed: int = 0
    init: str = ""                   # start from these weights (fine-tuning)
    color_jitter: bool = True        # ColorJitter on every crop (off: the ablation's variant)
    boundary_head: bool = True       # learn the leaf boundary too (needs samples with leaf_edge)


def LoadSamples(folder: Path) -> list[dict]:
    out = []
    for f in sorted(folder.glob("[0-9]*.npz")):
        if ".tmp" in f.name:
            continue
        d = np.load(f, allow_pickle=False)
        out.append({"seed": int(f.stem), "x": d["inputs"], "y": d["truth"].astype(np.int64),
                    "e": d["leaf_edge"] if "leaf_edge" in d.files else None,
                    "kind": str(d["fruit_kind"]),
                    "multi": bool(d["multi"]) if "multi" in d.files else False,
                    "held": bool(d["held"]) if "held" in d.files else False,
                    "greenhouse": bool(d["greenhouse"]) if "greenhouse" in d.files else False})
    return out


def RandomCrop(sample: dict, rng: np.random.Generator, size: int = CROP,
               jitter: bool = True):
    x, y = sample["x"], sample["y"]
    H, W = y.shape
    fruit = np.argwhere(y == 3)
    plant = np.argwhere(y > 0)
    other = np.argwhere((y == 0) & (x[3] > 0))   # returns that are not plant: the robot
    band = np.argwhere(sample["e"] == 1) if sample.get("e") is not None else fruit[:0]
    r = rng.random()
    if len(band):          # a leaf boundary target: 15 % of the crops on the band
        pool = (fruit if r < 0.35 and len(fruit) else band if r < 0.5 else
                other if r > 0.75 and len(other) else plant)
    else:
        pool = (fruit if r < 0.45 and len(fruit) else
                other if r > 0.7 and len(other) else plant)
    cy, cx = pool[rng.integers(len(pool))] + rng.integers(-size // 3, size // 3 + 1, 2)
    y0 = int(np.clip(cy - size // 2, 0, max(H - size, 0)))
    x0 = int(np.clip(cx - size // 2, 0, max(W - size, 0)))
    xc = np.zeros((x.shape[0], size, size), np.float32)
    yc = np.zeros((size, size), np.int64)
    ec = np.full((size, size), IGNORE, np.int64)
    xs = x[:, y0:y0 + size, x0:x0 + size].astype(np.float32)
    ys = y[y0:y0 + size, x0:x0 + size]
    xc[:, :xs.shape[1], :xs.shape[2]] = xs
    yc[:ys.shape[0], :ys.shape[1]] = ys
    if sample.get("e") is not None:
        ec[:ys.shape[0], :ys.shape[1]] = sample["e"][y0:y0 + size, x0:x0 + size]
    if rng.random() < 0.5:  # horizontal flip: mirror columns, negate the normal's x
        xc = xc[:, :, ::-1].copy()
        yc = yc[:, ::-1].copy()
        ec = ec[:, ::-1].copy()
        xc[5] *= -1.0
    if jitter:
        xc[:3] = ColorJitter(xc[:3] + 0.5, rng) - 0.5
    return xc, yc, ec


def HueRotation(deg: float) -> np.ndarray:
    """3x3 RGB matrix turning colours by ``deg`` about the grey axis (a hue
    shift that keeps grey grey)."""
    a = np.radians(deg)
    k = np.ones(3) / np.sqrt(3.0)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


def ColorJitter(rgb: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A (3, H, W) RGB crop in [0, 1] with a random gain (0.75-1.25), white
    balance (per channel 0.9-1.1), and with probability 0.5 a hue shift of
    up to 10 deg, 0.25 a Gaussian blur (0.5-1.2 px), 0.5 pixel noise
    (sigma 0.005-0.03); clipped to [0, 1]."""
    x = rgb * rng.uniform(0.75, 1.25) * rng.uniform(0.9, 1.1, (3, 1, 1))
    if rng.random() < 0.5:
        x = np.einsum("ij,jhw->ihw", HueRotation(rng.uniform(-10, 10)), x)
    if rng.random() < 0.25:
        x = ndimage.gaussian_filter(x, (0, *[rng.uniform(0.5, 1.2)] * 2))
    if rng.random() < 0.5:
        x = x + rng.normal(0, rng.uniform(0.005, 0.03), x.shape)
    return np.clip(x, 0.0, 1.0).astype(np.float32)


def Iou(pred: np.ndarray, truth: np.ndarray, c: int) -> float:
    a, b = pred == c, truth == c
    u = (a | b).sum()
    return float("nan") if u == 0 else float((a & b).sum() / u)


def Validate(net, samples: list[dict]) -> dict:
    net.eval()
    rows = []
    edge_counts = np.zeros(3, np.int64)     # boundary pixels: hit, predicted, true
    for s in samples:
        out = PredictLogits(net, s["x"].astype(np.float32))
        pred = out[:NUM_CLASSES].argmax(0)
        if len(out) > NUM_CLASSES and s.get("e") is not None:
            m = (s["y"] == LEAF) & (s["e"] != IGNORE)
            edge_counts += BandCounts((out[NUM_CLASSES] > 0)[m], s["e"][m] == 1)
        rows.append({"kind": s["kind"], "multi": s["multi"], "held": s["held"],
                     "greenhouse": s.get("greenhouse", False),
                     **{k: Iou(pred, s["y"], c)
                                         for k, c in (("branch", 1), ("leaf", 2), ("fruit", 3))}})
    net.train()

    def mean(rs, k):
        v = [r[k] for r in rs if not math.isnan(r[k])]
        return round(float(np.mean(v)), 4) if v else None
    green = [r for r in rows if r["kind"] == "green"]
    other = [r for r in rows if r["kind"] != "green"]
    out = {"n": len(rows), "branch_iou": mean(rows, "branch"), "leaf_iou": mean(rows, "leaf"),
           "fruit_iou_green": mean(green, "fruit"), "fruit_iou_other": mean(other, "fruit")}
    multi = [r for r in rows if r["multi"]]
    if multi:       # the multi-fruit plants among them (side shoots and stalks)
        out.update(n_multi=len(multi), fruit_iou_multi=mean(multi, "fruit"),
                   branch_iou_multi=mean(multi, "branch"))
    held = [r for r in rows if r["held"]]
    if held:        # a leaf held by the gripper, turned (make_segnet_data.py --held_leaf)
        out.update(n_held=len(held), leaf_iou_held=mean(held, "leaf"),
                   fruit_iou_held=mean(held, "fruit"))
    if edge_counts[2] > 0:  # the boundary head on truth leaf pixels
        precision, recall = BandPrecisionRecall(edge_counts)
        out.update(boundary_precision=precision or 0.0, boundary_recall=recall)
    gh = [r for r in rows if r["greenhouse"]]
    if gh:          # greenhouse scenes (make_segnet_data.py --greenhouse)
        out.update(n_greenhouse=len(gh), **{f"{k}_iou_greenhouse": mean(gh, k)
                                            for k in ("fruit", "leaf", "branch")})
    return out


def TrainSteps(net, draw, steps: int, batch: int, lr: float, desc: str) -> None:
    """``steps`` Adam steps (cosine learning-rate decay from ``lr``) of the
    class-weighted cross-entropy (leaf and fruit weighted 2) on batches of
    ``batch`` crops, each ``draw()``: (input, class target, boundary
    target) as ``RandomCrop`` gives; with the network's boundary head, its
    loss is added (``BOUNDARY_WEIGHT``); a progress bar named ``desc``
    shows the loss."""
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    weight = torch.tensor([1.0, 2.0, 1.0, 2.0])
    bar = tqdm(range(steps), desc=desc, unit="step")
    for step in bar:
        crops = [draw() for _ in range(batch)]
        x = torch.from_numpy(np.stack([b[0] for b in crops]))
        y = torch.from_numpy(np.stack([b[1] for b in crops]))
        out = net(x)
        loss = torch.nn.functional.cross_entropy(out[:, :NUM_CLASSES], y, weight=weight)
        if out.shape[1] > NUM_CLASSES:
            e = torch.from_numpy(np.stack([b[2] for b in crops]))
            m = (y == LEAF) & (e != IGNORE)
            if m.any():
                loss = loss + BOUNDARY_WEIGHT * torch.nn.functional.binary_cross_entropy_with_logits(
                    out[:, NUM_CLASSES][m], e[m].float(),
                    pos_weight=torch.tensor(BOUNDARY_POS_WEIGHT))
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if step % 20 == 0:
            bar.set_postfix(loss=f"{loss.item():.3f}")


def WithBoundaryHead(net: SegNet, boundary_head: bool) -> SegNet:
    """``net`` itself when it has (or should not have) the boundary head;
    else a copy with it added: every weight kept, the new channel's weights
    zero and its bias -2 (probability 0.12: nowhere a boundary yet)."""
    if net.boundary_head or not boundary_head:
        return net
    new = SegNet(net.widths, boundary_head=True)
    state = net.state_dict()
    w, b = state.pop("head.weight"), state.pop("head.bias")
    new.load_state_dict(state, strict=False)
    with torch.no_grad():
        new.head.weight.zero_()
        new.head.weight[:NUM_CLASSES] = w
        new.head.bias.fill_(-2.0)
        new.head.bias[:NUM_CLASSES] = b
    new.meta = getattr(net, "meta", {})
    return new


def TrainSegNet(args: SegNetTrainingOptions) -> dict:
    """Trains the network (see the module docstring), writes ``args.out``
    and its ``.json``, prints and returns the meta. Raises InputError when
    ``args.data`` holds fewer than 10 samples."""
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    samples = LoadSamples(Path(args.data))
    if len(samples) < 10:
        raise InputError(f"{args.data} holds {len(samples)} samples; make more with "
                         "scripts/make_segnet_data.py")
    val = [s for s in samples if s["seed"] % 10 == 0]
    train = [s for s in samples if s["seed"] % 10 != 0]
    net = SegNet(boundary_head=args.boundary_head)
    if args.init:
        net = WithBoundaryHead(LoadSegNet(args.init), args.boundary_head).train()
    t0 = time.time()
    TrainSteps(net, lambda: RandomCrop(train[rng.integers(len(train))], rng,
                                       jitter=args.color_jitter),
               args.steps, args.batch, args.lr, "training")
    metrics = Validate(net, val)
    meta = {"init": args.init, "boundary_head": args.boundary_head,
            "boundary_samples": sum(s["e"] is not None for s in samples),
            "train_samples": len(train), "val_samples": len(val), "steps": args.steps,
            "batch": args.batch, "lr": args.lr, "crop": CROP, "color_jitter": args.color_jitter,
            "multi_samples": sum(s["multi"] for s in samples),
            "held_samples": sum(s["held"] for s in samples),
            "greenhouse_samples": sum(s["greenhouse"] for s in samples), "seconds": round(time.time() - t0, 1),
            "data": str(args.data), "seed_range": [min(s["seed"] for s in samples),
                                                   max(s["seed"] for s in samples)],
            "validation": metrics}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    SaveSegNet(net, out, meta)
    out.with_suffix(".json").write_text(json.dumps(meta, indent=2))
    print(json.dumps(meta, indent=2))
    return meta
