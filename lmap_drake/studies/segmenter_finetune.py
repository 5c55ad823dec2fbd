"""``lmap-drake train-segmenter``: fine-tunes the segmentation network
(``segnet``) on a lab's own captures.

Input: run folders with recordings (``DIR/*/recording/``, the project's
recording format) and polygon annotations of their colour images
(``lmap_drake.perception.annotations``): a COCO file (``--annotations
FILE``; each image's ``file_name`` names a recorded colour image, e.g.
``run3/recording/view0_rgb.png``, relative to DIR or by its last parts), or
LabelMe files beside the images (``view<k>_rgb.json``, found when
``--annotations`` is not given). Every 5th annotated view (at least one)
is held out. Training starts from the shipped weights (``--init``), mixes
the annotated views with simulated samples (``--sim_data``, a folder of
``scripts/make_segnet_data.py``; ``--sim_fraction`` of each batch), and
writes the new weights (``--out``, never over the input) with their
``.json``; it prints the held-out IoU before and after. When the weights
carry the leaf boundary head, it is fine-tuned too, on the seams between
the annotated leaf polygons (one polygon object per leaf).
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import torch

from lmap_drake.errors import InputError
from lmap_drake.labels import LeafBoundaryMask
from lmap_drake.paths import REPO_ROOT
from lmap_drake.perception.annotations import Annotation, LoadCoco, LoadLabelMe
from lmap_drake.perception.points import Intrinsics
from lmap_drake.perception.recording import LoadRecording
from lmap_drake.perception.segnet import (NUM_CLASSES, CropBox, LoadSegNet, PredictLogits, SaveSegNet,
                                          SegNetInputs)
from lmap_drake.perception.training import Iou, LoadSamples, RandomCrop, TrainSteps
from lmap_drake.scenario import LoadScenario

HOLDOUT_EVERY = 5


class FineTuneError(InputError):
    """The recordings, annotations or options cannot make a fine-tuning."""


def _Match(ann: Annotation, views: dict) -> str | None:
    """The recorded view whose colour image the annotation names."""
    name = ann.image.replace("\\", "/").lstrip("./")
    hits = [k for k in views if k == name or k.endswith("/" + name)]
    if len(hits) > 1:
        raise FineTuneError(f"annotation image '{ann.image}' matches several recorded views "
                            f"({', '.join(hits[:3])}); give it as <run>/recording/<file>")
    return hits[0] if hits else None


def AnnotatedViews(recordings: Path, annotations: Path | None, depth_cut: float) -> list[dict]:
    """The annotated recorded views as samples {"name", "x", "y"} cropped
    to the returns within the depth cut (``SegNetInputs``, class map)."""
    recordings = Path(recordings)
    if not recordings.is_dir():
        raise FineTuneError(f"--recordings {recordings}: no such folder")
    runs = sorted(d for d in recordings.iterdir()
                  if (d / "recording" / "recording.json").is_file())
    views = {}
    for run in runs:
        rec = LoadRecording(run)
        K = Intrinsics(int(rec.camera["width"]), int(rec.camera["height"]), rec.camera["fx"],
                       rec.camera["fy"], rec.camera["cx"], rec.camera["cy"])
        for entry, v in zip(json.loads((rec.folder / "recording.json").read_text())["views"],
                            rec.views):
            views[f"{run.name}/recording/{entry['rgb']}"] = (v, K, rec.folder / entry["rgb"])
    if annotations is not None:
        anns = list(LoadCoco(annotations).values())
    else:
        anns = []
        for key, (_, _, rgb_file) in views.items():
            f = rgb_file.with_suffix(".json")
            if f.is_file():
                a = LoadLabelMe(f)
                a.image = key
                anns.append(a)
    samples = []
    for a in anns:
        key = _Match(a, views)
        if key is None:
            raise FineTuneError(f"annotation image '{a.image}' is not a recorded colour image "
                                f"under {recordings} (e.g. run3/recording/view0_rgb.png)")
        v, K, _ = views[key]
        H, W = v.depth.shape
        if (a.width, a.height) != (W, H):
            raise FineTuneError(f"annotation of '{a.image}' is {a.width} x {a.height}, the "
                                f"image {W} x {H}")
        x = SegNetInputs(v.rgb, v.depth, K, depth_cut)
        y = a.ClassMap()
        box = CropBox((x[3] > 0) | (y > 0), 24)
        if box is None:
            continue
        edge = LeafBoundaryMask(a.LeafIds()).astype(np.uint8)   # where two annotated leaves meet
        samples.append({"name": key, "x": x[:, box[0], box[1]], "y": y[box], "e": edge[box]})
    if len(samples) < 2:
        source = (f"--annotations {annotations}" if annotations else
                  "LabelMe view<k>_rgb.json files")
        raise FineTuneError(f"{len(samples)} annotated views found under {recordings} "
                            f"({source}); fine-tuning needs at least 2 (one is held out)")
    return samples


def HeldOutIou(net, samples: list[dict]) -> dict:
    """Mean per-class IoU of ``net`` over ``samples`` (classes present)."""
    net.eval()
    rows = [(PredictLogits(net, s["x"].astype(np.float32))[:NUM_CLASSES].argmax(0), s["y"])
            for s in samples]
    out = {}
    for k, c in (("fruit_iou", 3), ("leaf_iou", 2), ("branch_iou", 1)):
        v = [Iou(p, y, c) for p, y in rows]
        v = [x for x in v if not np.isnan(x)]
        out[k] = round(float(np.mean(v)), 4) if v else None
    return out


def FineTuneSegmenter(args) -> dict:
    """Fine-tunes (module docstring); returns the meta written beside the weights."""
    if not 0.0 <= args.sim_fraction < 1.0:
        raise FineTuneError(f"--sim_fraction must be in [0, 1), got {args.sim_fraction}")
    if args.steps < 1 or args.batch < 1:
        raise FineTuneError("--steps and --batch must be >= 1")
    perception = LoadScenario(scenario_text=args.scenario_text).perception
    init = Path(args.init or perception.segnet_weights)
    init = init if init.is_absolute() else REPO_ROOT / init
    out = Path(args.out)
    if out.resolve() == init.resolve():
        raise FineTuneError(f"--out {out} is the weights being fine-tuned; write elsewhere")
    net = LoadSegNet(init)
    samples = AnnotatedViews(args.recordings, args.annotations, perception.depth_cut)
    held = samples[::HOLDOUT_EVERY]
    train = [s for i, s in enumerate(samples) if i % HOLDOUT_EVERY]
    sim = []
    if args.sim_data is not None:
        sim = LoadSamples(Path(args.sim_data))
        if not sim:
            raise FineTuneError(f"--sim_data {args.sim_data} holds no samples "
                                f"(scripts/make_segnet_data.py writes them)")
    before = HeldOutIou(net, held)
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    net.train()
    t0 = time.time()
    TrainSteps(net, lambda: RandomCrop(
        sim[rng.integers(len(sim))] if sim and rng.random() < args.sim_fraction
        else train[rng.integers(len(train))], rng), args.steps, args.batch, args.lr,
        "train-segmenter")
    after = HeldOutIou(net, held)
    meta = {"init": str(init), "recordings": str(args.recordings),
            "annotations": str(args.annotations) if args.annotations else "labelme",
            "train_views": [s["name"] for s in train], "held_out_views": [s["name"] for s in held],
            "sim_data": str(args.sim_data) if args.sim_data else None,
            "sim_samples": len(sim), "sim_fraction": args.sim_fraction if sim else 0.0,
            "steps": args.steps, "batch": args.batch, "lr": args.lr, "seed": args.seed,
            "seconds": round(time.time() - t0, 1),
            "held_out_iou_before": before, "held_out_iou_after": after}
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".partial")
    tmp_json = out.with_name(out.name + ".json.partial")
    SaveSegNet(net, tmp, meta)
    tmp_json.write_text(json.dumps(meta, indent=2))
    tmp_json.replace(out.with_suffix(".json"))
    tmp.replace(out)                              # the weights last: complete or not at all
    print(f"held-out IoU ({len(held)} views) before: {before}")
    print(f"held-out IoU after {args.steps} steps: {after}")
    print(f"weights: {out} (use: {{perception: {{segnet_weights: {out.resolve()}}}}})")
    return meta
