"""What each randomisation of the greenhouse training renders buys, measured
on held-out greenhouse plants (``scripts/ablate_segnet.py``).

One variant per randomisation group: the same greenhouse training seeds
rendered with that group at its plain setting
(``segnet_greenhouse.GREENHOUSE_RANDOMISATIONS``: textures, clutter, lights,
photometric, camera pose), or trained without the per-crop colour jitter
(``no_color_jitter``: gain, white balance, hue, blur, pixel noise), against
``all`` (everything on). Each variant fine-tunes the same start weights
(by default the one-leaf world's ``segnet.pt``, which has seen no greenhouse
look) with the same steps and crop draws, and is scored by
``EvalRecordings`` on still views of random greenhouse plants drawn from
their own seed (``RandomGreenhouseSuite``: 1-3 stems, 15-60 leaves; 3-stem
plants and plants over 45 leaves are never rendered for training), with the
L515 noise model and the suite's greenhouse lights. ``all`` is trained with
two training seeds: the spread between them is the noise level below which
a variant's difference means nothing.

Outputs in ``OUT/``: ``ablation.json`` (per variant the mean fruit / leaf /
branch IoU, green fruit IoU, phantom fruit instances per view and the
differences from ``all``), ``ablation.md`` (the table) and ``ablation.png``
(bars); the renders, weights and per-variant evaluations stay in
``OUT/work/`` so that a run resumes where it stopped.
"""
from __future__ import annotations

import dataclasses as dc
import json
import time
from pathlib import Path

import numpy as np

from lmap_drake.errors import InputError
from lmap_drake.perception.recording import CapturedView, SaveRecording
from lmap_drake.perception.points import Intrinsics
from lmap_drake.perception.training import SegNetTrainingOptions, TrainSegNet
from lmap_drake.plants.greenhouse_suite import GreenhouseSuiteYaml, RandomGreenhouseSuite
from lmap_drake.plants.plant_station import RenderStill
from lmap_drake.scenario import LoadScenario, ScenarioNames
from lmap_drake.studies.segmentation import EvalRecordings
from lmap_drake.studies.segnet_data import MakeSegNetData
from lmap_drake.studies.segnet_greenhouse import GREENHOUSE_RANDOMISATIONS

# variant -> (greenhouse randomisations left plain, colour jitter in training, training seed)
VARIANTS = {"all": ((), True, 0), "all_seed1": ((), True, 1),
            **{f"no_{g}": ((g,), True, 0) for g in GREENHOUSE_RANDOMISATIONS},
            "no_color_jitter": ((), False, 0)}


@dc.dataclass
class AblationOptions:
    """The study's settings (the flags of ``scripts/ablate_segnet.py``)."""
    out: str = "out/segnet_ablation"
    variants: tuple = tuple(VARIANTS)
    count: int = 60             # greenhouse training renders per variant (seeds seed..seed+count-1)
    seed: int = 90000
    steps: int = 250
    lr: float = 1e-3
    init: str = "models/segnet/segnet.pt"
    heldout: int = 8            # random greenhouse plants scored
    heldout_seed: int = 6161
    workers: int = 1
    threads: int = 2


def CheckOptions(o: AblationOptions) -> None:
    """InputError naming the flag, before anything is rendered."""
    unknown = [v for v in o.variants if v not in VARIANTS]
    if unknown:
        raise InputError(f"--variants: unknown {unknown}; known: {', '.join(VARIANTS)}")
    if "all" not in o.variants:
        raise InputError("--variants must include 'all' (the reference)")
    if min(o.count, o.steps, o.heldout, o.workers, o.threads) < 1:
        raise InputError("--count, --steps, --heldout, --workers and --threads must be >= 1")
    if not Path(o.init).is_file():
        raise InputError(f"--init: weights file not found: {o.init}")


def HeldOutStills(folder: Path, n: int, seed: int) -> Path:
    """Renders one still per random greenhouse plant (``RandomGreenhouseSuite(n,
    seed)``, its scenario file written beside) as project recordings with
    label images under ``folder``; existing complete recordings are kept."""
    folder.mkdir(parents=True, exist_ok=True)
    suite_file = folder / "heldout.yaml"
    if not suite_file.is_file():
        text = GreenhouseSuiteYaml(RandomGreenhouseSuite(n, seed),
                                   f"# held-out greenhouse plants (seed {seed})", seed=seed)
        tmp = suite_file.with_suffix(".partial")
        tmp.write_text(text)
        tmp.replace(suite_file)
    for name in ScenarioNames(suite_file):
        if (folder / name / "recording" / "recording.json").is_file():
            continue
        s = LoadScenario(filename=suite_file, scenario_name=name)
        s.plant_scene.greenhouse.max_fem_leaves = 0    # a still needs no FEM (same rest shape)
        rgb, depth, label = RenderStill(s)
        cam = s.cameras["camera0"]
        K = Intrinsics.FromCameraConfig(cam)
        view = CapturedView(0, 0.0, time.time(), rgb, depth, label, np.zeros(6), np.zeros(6),
                            np.full(3, np.nan))
        SaveRecording(folder / name, [view], dict(width=K.width, height=K.height, fx=K.fx,
                                                 fy=K.fy, cx=K.cx, cy=K.cy),
                      cam.X_PB.GetDeterministicValue().GetAsMatrix4(), "simulation")
    return folder


def _Row(ev: dict) -> dict:
    r = ev["segnet"]
    return {**{k: r["mean"][k] for k in ("fruit_iou", "leaf_iou", "branch_iou")},
            "green_fruit_iou": r["per_fruit_color"].get("green", {}).get("fruit_iou"),
            "phantom_fruits_per_view": r["phantom_fruits_per_view"]}


def RunAblation(o: AblationOptions) -> dict:
    """Renders, trains and scores every variant (see the module docstring);
    writes and returns the summary."""
    CheckOptions(o)
    out = Path(o.out)
    work = out / "work"
    heldout = HeldOutStills(work / "heldout", o.heldout, o.heldout_seed)
    rows = {}
    for name in o.variants:
        off, jitter, train_seed = VARIANTS[name]
        data = work / ("data_all" if not off else f"data_no_{'_'.join(off)}")
        MakeSegNetData(data, count=o.count, seed=o.seed, workers=o.workers, arm_near_leaf=0.0,
                       greenhouse=1.0, greenhouse_off=off)
        weights = work / f"{name}.pt"
        if not weights.with_suffix(".json").is_file():   # the .json is written last
            tmp = work / f"{name}.partial.pt"
            TrainSegNet(SegNetTrainingOptions(
                data=str(data), out=str(tmp), steps=o.steps, lr=o.lr, init=o.init,
                threads=o.threads, seed=train_seed, color_jitter=jitter))
            tmp.replace(weights)
            tmp.with_suffix(".json").replace(weights.with_suffix(".json"))
        ev_file = work / f"eval_{name}.json"
        ev = (json.loads(ev_file.read_text()) if ev_file.is_file() else EvalRecordings(
            ev_file, heldout, backends=("segnet",), pictures=False,
            scenario_text=f"{{perception: {{segnet_weights: {weights}}}}}"))
        rows[name] = {"off": list(off), "color_jitter": jitter, "training_seed": train_seed,
                      **_Row(ev)}
    ref = rows["all"]
    for r in rows.values():
        r["delta"] = {k: (None if r[k] is None or ref[k] is None else round(r[k] - ref[k], 3))
                      for k in ("fruit_iou", "leaf_iou", "branch_iou", "green_fruit_iou",
                                "phantom_fruits_per_view")}
    summary = {"options": dc.asdict(o), "plain_settings": GREENHOUSE_RANDOMISATIONS,
               "heldout": str(heldout), "variants": rows}
    out.mkdir(parents=True, exist_ok=True)
    tmp = out / "ablation.json.partial"
    tmp.write_text(json.dumps(summary, indent=2))
    tmp.replace(out / "ablation.json")
    (out / "ablation.md").write_text(AblationTable(summary))
    AblationFigure(summary, out / "ablation.png")
    print(AblationTable(summary))
    return summary


def AblationTable(summary: dict) -> str:
    """The summary as a Markdown table (IoU and the difference from ``all``)."""
    lines = ["| variant | fruit IoU | leaf IoU | branch IoU | green fruit IoU | phantoms / view |",
             "|---|---|---|---|---|---|"]

    def cell(r, k):
        v, d = r[k], r["delta"][k]
        return "-" if v is None else f"{v:.3f}" + ("" if d is None else f" ({d:+.3f})")
    for name, r in summary["variants"].items():
        lines.append(f"| {name} | " + " | ".join(
            cell(r, k) for k in ("fruit_iou", "leaf_iou", "branch_iou", "green_fruit_iou",
                                 "phantom_fruits_per_view")) + " |")
    return "\n".join(lines) + "\n"


def AblationFigure(summary: dict, path: Path) -> None:
    """Bars of fruit / leaf / branch IoU per variant."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    names = list(summary["variants"])
    keys = ("fruit_iou", "leaf_iou", "branch_iou")
    fig, ax = plt.subplots(figsize=(1.2 * len(names) + 2, 3.5))
    for k, key in enumerate(keys):
        vals = [summary["variants"][n][key] or 0.0 for n in names]
        ax.bar(np.arange(len(names)) + (k - 1) * 0.27, vals, 0.27, label=key.replace("_iou", ""))
    ax.set_xticks(np.arange(len(names)), names, rotation=30, ha="right")
    ax.set_ylim(0, 1)
    ax.set_ylabel("IoU on held-out plants")
    ax.legend(ncol=3, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
