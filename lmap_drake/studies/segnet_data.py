"""Randomised simulator renders for training the segmentation network
(``lmap_drake/perception/segnet.py``): domain randomisation of the plant
(random pepper family shapes, sizes, tilts, occlusion 0.3-0.95, leaf and
branch sizes), of every colour (leaf, branch, fruit with half of the fruits
green, stripes, background), of the lights (1-3 directional lights, tinted),
of the camera pose (+-8 cm, +-8 deg around the default) and arm pose, and of
the camera model (depth noise 0.5-2x, dropout and flying-pixel rates).
With ``--held_leaf F``, a fraction F of the scenes shows a leaf held by the
gripper the way the planner's actions leave it (``HeldLeaf``): grasped at
one of the planner's own grasp points, turned about its petiole attachment
by a twist (20-70 deg about the attachment-grasp line), an arc (10-50 deg
about an axis across it) or both, and pulled up to 4 cm, the arm at the
turned grasp (``plants.leaf.TurnHeldLeaf``: the blade turns as one piece
beyond the petiole). Without such views the network took most of a held,
turned leaf for background. With ``--greenhouse F``, a fraction F of the
scenes is a random greenhouse plant instead (``segnet_greenhouse``:
textures, dressing, neighbouring row, greenhouse lights, exposure and
white balance), its neighbouring row truth leaf / branch.

    python scripts/make_segnet_data.py --out out/segnet_data --count 400 --seed 10000

Each sample ``NNNNN.npz`` holds the network input (``SegNetInputs``, float16,
cropped to the plant and robot returns plus a margin) and the truth class
map (uint8, background / branch / leaf / fruit; the robot is background),
``leaf_edge`` (uint8: 1 on the band where two leaves meet in the image,
``labels.LeafBoundaryMask``; 255 on neighbouring-row leaves, whose leaves
the render does not tell apart; else 0),
with ``fruit_kind`` (red / orange / yellow / green; ``mixed`` for a
multi-fruit plant not all green) and ``multi`` (a multi-fruit plant,
``--multi``), ``greenhouse`` (a greenhouse scene). Sample ``i`` depends only
on ``seed + i``, so a run can be extended or resumed (existing files are
kept). Seeds used here must stay apart from the evaluation suites'
(``RandomSuite(N, S)`` draws plants from its own seed ``S`` and never uses
these colours or lights).
"""
from __future__ import annotations

import colorsys
import multiprocessing as mp
import time
from pathlib import Path

import numpy as np
from pydrake.common.schema import Rotation
from pydrake.geometry import LightParameter, Rgba
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from tqdm import tqdm

from lmap_drake.errors import InputError
from lmap_drake.perception.points import Intrinsics
from lmap_drake.labels import LEAF, NEIGHBOUR, LeafBoundaryMask, NeighbourClassMap, TrueLeafIds
from lmap_drake.perception.segmentation import TruthClassMap
from lmap_drake.perception.segnet import CropBox, SegNetInputs
from lmap_drake.planning.candidates import GraspCandidates
from lmap_drake.planning.robot_model import RobotModel
from lmap_drake.plants.leaf import TurnHeldLeaf
from lmap_drake.plants.multi import MULTI_KINDS
from lmap_drake.plants.suite import RandomMultiSuite, RandomSuite
from lmap_drake.plants.plant_station import GetPlantModel, RenderStill
from lmap_drake.scenario import Scenario
from lmap_drake.studies.segnet_greenhouse import RandomDepthNoise, RandomGreenhouseRenderScenario

FRUIT_KINDS = ("red", "orange", "yellow", "green")
FRUIT_HUES = {"red": (-8.0, 8.0), "orange": (18.0, 32.0), "yellow": (40.0, 55.0),
              "green": (75.0, 130.0)}


def _rgba(h_deg: float, s: float, v: float):
    return Rgba(*colorsys.hsv_to_rgb((h_deg % 360.0) / 360.0, s, v), 1.0)


def _ArmNearLeaf(s, rng) -> list[float]:
    """UR5 joints (IK) with the TCP at a random leaf point, approaching from
    the camera's side within 50 deg; the scenario's joints if IK fails."""
    model = GetPlantModel(s)
    leaf = (model.leaves[rng.integers(len(model.leaves))].rest_W if hasattr(model, "leaves")
            else model.leaf_rest_W)      # a multi-fruit plant: one of its leaves
    p = leaf[rng.integers(len(leaf))]
    p_WC = s.cameras["camera0"].X_PB.GetDeterministicValue().translation()
    z = p - p_WC
    z = z / np.linalg.norm(z) + rng.normal(0, 0.45, 3)
    z /= np.linalg.norm(z)
    x = np.cross(z, rng.normal(size=3))
    x /= np.linalg.norm(x)
    R = RotationMatrix(np.c_[x, np.cross(z, x), z])
    robot = RobotModel(s.robot.X_WB.GetDeterministicValue())
    r = robot.Ik(RigidTransform(R, p - z * rng.uniform(0.0, 0.03)), np.asarray(s.robot.initial_q),
                 0.01, multistart=True)
    return [float(v) for v in r.q] if r.success else list(s.robot.initial_q)


def HeldLeaf(s, rng, kind: str | None = None, twist_deg: float | None = None,
             arc_deg: float | None = None, pull_m: float | None = None) -> dict:
    """Turns one leaf of ``s``'s plant as a held one (see the module
    docstring) and puts the closed gripper at its turned grasp point: sets
    ``s.robot.initial_q`` and ``initial_gripper_width``; returns
    ``RenderStill``'s ``leaf_positions``. ``kind`` (twist / arc / both) and
    the angles and pull length are drawn from ``rng`` unless given. Raises
    ValueError when the leaf has no grasp or the arm cannot reach the
    turned grasp."""
    model = GetPlantModel(s)
    if hasattr(model, "leaves"):
        j = int(rng.integers(len(model.leaves)))
        rest, attach = model.leaves[j].rest_W, model.leaves[j].attach_W
        branch = np.vstack([b.points_W for b in model.branches])
    else:
        j, rest, attach, branch = 0, model.leaf_rest_W, model.leaf_attach_W, model.branch_points_W
    p_WC = s.cameras["camera0"].X_PB.GetDeterministicValue().translation()
    grasps, _ = GraspCandidates(rest, branch, p_WC, 15, 0.01, 0.03)
    grasps = [g for g in grasps if np.linalg.norm(g.p_WG - attach) > 0.04]
    if not grasps:
        raise ValueError("no grasp on the held leaf")
    g = grasps[int(rng.integers(len(grasps)))]
    line = (g.p_WG - attach) / np.linalg.norm(g.p_WG - attach)
    across = np.cross(line, rng.normal(size=3))
    across /= np.linalg.norm(across)
    kind = kind or str(rng.choice(["twist", "arc", "both"]))
    arc = np.radians(arc_deg if arc_deg is not None else rng.uniform(10, 50))
    twist = np.radians(twist_deg if twist_deg is not None
                       else rng.uniform(20, 70) * rng.choice([-1.0, 1.0]))
    pull = rng.normal(size=3)
    pull *= (pull_m if pull_m is not None
             else min(0.04, 0.02 * float(np.linalg.norm(pull)))) / float(np.linalg.norm(pull))
    pts, R = rest, np.eye(3)
    if kind in ("arc", "both"):
        pts, R1 = TurnHeldLeaf(pts, attach, g.p_WG, across, arc)
        R = R1 @ R
    p_grasp = attach + R @ (g.p_WG - attach)
    if kind in ("twist", "both"):
        pts, R2 = TurnHeldLeaf(pts, attach, p_grasp, p_grasp - attach, twist)
        R = R2 @ R
    pts, _ = TurnHeldLeaf(pts, attach, p_grasp, line, 0.0, pull_W=pull)
    robot = RobotModel(s.robot.X_WB.GetDeterministicValue())
    X = RigidTransform(RotationMatrix(R @ g.R_WG), p_grasp + pull)
    r = robot.Ik(X, np.asarray(s.robot.initial_q), 0.01, multistart=True)
    if not r.success:
        raise ValueError("the arm cannot reach the held leaf's grasp")
    s.robot.initial_q = [float(v) for v in r.q]
    s.robot.initial_gripper_width = float(rng.uniform(0.0, 0.006))
    return {j: pts}


def _RandomFruitColor(rng, fruit) -> str:
    """A random fruit kind (half green) and colour on ``fruit`` (a
    ``FruitConfig``); returns the kind."""
    kind = str(rng.choice(FRUIT_KINDS, p=[0.2, 0.15, 0.15, 0.5]))
    lo, hi = FRUIT_HUES[kind]
    if kind == "green":
        fruit.color = _rgba(rng.uniform(lo, hi), rng.uniform(0.45, 0.9), rng.uniform(0.25, 0.65))
    else:
        fruit.color = _rgba(rng.uniform(lo, hi), rng.uniform(0.8, 1.0), rng.uniform(0.55, 0.95))
    fruit.stripe_color = Rgba(*(np.asarray(fruit.color.rgba[:3]) * rng.uniform(0.6, 0.85)), 1.0)
    return kind


def RandomRenderScenario(seed: int, arm_near_leaf: float = 0.0, multi: float = 0.0,
                         held_leaf: float = 0.0):
    """(Scenario, fruit_kind) for sample ``seed``: a random procedural plant
    with randomised colours, lights, camera pose, arm pose and camera model;
    with probability ``arm_near_leaf`` the gripper is at the leaf. With
    probability ``multi`` the plant has 2-4 fruits on side shoots, each with
    its stalk, and 2-6 leaves (``RandomMultiSuite``), each fruit its own
    colour; its kind is then ``green`` if every fruit is, else ``mixed``.
    Returns (Scenario, fruit_kind, leaf_positions): with probability
    ``held_leaf`` (its own coin) a leaf is held and turned (``HeldLeaf``;
    its vertices for ``RenderStill``), else leaf_positions is empty."""
    rng = np.random.default_rng(seed)
    s = Scenario()
    s.random_seed = int(seed)
    # (the coin has its own stream: a single plant's sample is the same
    # whatever ``multi`` is)
    is_multi = np.random.default_rng([seed, 1]).random() < multi
    plant = next(iter((RandomMultiSuite if is_multi else RandomSuite)(
        1, int(rng.integers(1 << 30))).values()))
    if not is_multi:
        plant.occlusion = float(rng.uniform(0.3, 0.95))
    plant.leaf.color = _rgba(rng.uniform(75, 135), rng.uniform(0.45, 0.85), rng.uniform(0.3, 0.7))
    plant.branch.color = _rgba(rng.uniform(40, 110), rng.uniform(0.3, 0.7), rng.uniform(0.22, 0.55))
    if is_multi:
        kinds = {_RandomFruitColor(rng, f.fruit) for f in plant.multi.fruits}
        kind = "green" if kinds == {"green"} else "mixed"
    else:
        kind = _RandomFruitColor(rng, plant.fruit)
    s.plant_scene = plant

    cam = s.cameras["camera0"]
    X = cam.X_PB.GetDeterministicValue()
    rpy = RollPitchYaw(X.rotation()).vector() + np.radians(rng.uniform(-8, 8, 3))
    cam.X_PB.translation = X.translation() + rng.uniform([-0.08, -0.12, -0.08], [0.08, 0.1, 0.08])
    cam.X_PB.rotation = Rotation(RollPitchYaw(rpy))
    cam.background = _rgba(rng.uniform(0, 360), rng.uniform(0, 0.5), rng.uniform(0.3, 0.95))

    lights = []
    for _ in range(int(rng.integers(1, 4))):
        light = LightParameter()
        light.type = "directional"
        light.frame = "camera"
        d = np.array([rng.uniform(-0.8, 0.8), rng.uniform(-0.8, 0.8), 1.0])
        light.direction = d / np.linalg.norm(d)
        light.intensity = float(rng.uniform(0.35, 1.1))
        light.color = Rgba(*(1.0 - rng.uniform(0, 0.15, 3)), 1.0)
        lights.append(light)
    s.lights = lights

    q = np.asarray(s.robot.initial_q) + np.concatenate([rng.uniform(-0.25, 0.25, 3), np.zeros(3)])
    s.robot.initial_q = [float(x) for x in q]
    if rng.random() < arm_near_leaf:
        # the arm where it is after a grasp: the gripper at the leaf, the
        # wrist and forearm in front of the plant (the "after" view)
        s.robot.initial_q = _ArmNearLeaf(s, rng)
        s.robot.initial_gripper_width = float(rng.uniform(0.0, 0.04))
    held = {}
    if np.random.default_rng([seed, 2]).random() < held_leaf:
        held = HeldLeaf(s, np.random.default_rng([seed, 3]))

    RandomDepthNoise(s.camera_noise, rng)
    return s, kind, held


def RenderSample(seed: int, margin: int = 24, arm_near_leaf: float = 0.0,
                 multi: float = 0.0, held_leaf: float = 0.0, greenhouse: float = 0.0,
                 greenhouse_off=()) -> dict:
    """Renders sample ``seed``; returns the arrays stored in its ``.npz``.
    With probability ``greenhouse`` (its own coin) a random greenhouse
    scene (``segnet_greenhouse``) instead; a neighbouring plant's pixels
    are truth leaf / branch; ``greenhouse_off`` names the greenhouse
    randomisations left plain (``GREENHOUSE_RANDOMISATIONS``)."""
    if np.random.default_rng([seed, 4]).random() < greenhouse:
        s, kind, held = RandomGreenhouseRenderScenario(seed, greenhouse_off)
    else:
        s, kind, held = RandomRenderScenario(seed, arm_near_leaf, multi, held_leaf)
    rgb, depth, label = RenderStill(s, leaf_positions=held)
    truth = TruthClassMap(label)
    nb = NeighbourClassMap(label)
    truth = np.where(nb > 0, nb, truth).astype(np.uint8)
    K = Intrinsics.FromCameraConfig(s.cameras["camera0"])
    x = SegNetInputs(rgb, depth, K, s.perception.depth_cut)
    box = CropBox((x[3] > 0) | (truth > 0), margin)
    if box is None or not (truth == 3).any():
        raise ValueError("no fruit in view")
    ids = TrueLeafIds(label)
    edge = np.where(ids == NEIGHBOUR + LEAF, 255, LeafBoundaryMask(ids)).astype(np.uint8)
    return {"inputs": x[:, box[0], box[1]].astype(np.float16), "truth": truth[box],
            "leaf_edge": edge[box],
            "fruit_kind": kind, "multi": s.plant_scene.kind in MULTI_KINDS, "held": bool(held),
            "greenhouse": s.plant_scene.kind == "greenhouse"}


def _work(args) -> str:
    seed, out, arm_near_leaf, multi, held_leaf, greenhouse, greenhouse_off = args
    path = Path(out) / f"{seed:06d}.npz"
    if path.exists():
        return "kept"
    try:
        sample = RenderSample(seed, arm_near_leaf=arm_near_leaf, multi=multi,
                              held_leaf=held_leaf, greenhouse=greenhouse,
                              greenhouse_off=greenhouse_off)
    except Exception as err:  # a generator refusal or an empty view: skip the seed
        return f"skipped {seed}: {type(err).__name__}: {err}"
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, **sample)
    tmp.rename(path)
    return "made"


def MakeSegNetData(out, count: int = 400, seed: int = 10000, workers: int = 2,
                   arm_near_leaf: float = 0.5, multi: float = 0.0,
                   held_leaf: float = 0.0, greenhouse: float = 0.0,
                   greenhouse_off=(), progress: bool = True) -> dict:
    """Renders samples ``seed`` .. ``seed + count - 1`` into the folder
    ``out`` (existing ones are kept) with ``workers`` processes; returns the
    counts made / kept / skipped. Raises InputError for a fraction outside
    [0, 1] or a count or worker number below 1."""
    if not all(0.0 <= v <= 1.0 for v in (multi, arm_near_leaf, held_leaf, greenhouse)):
        raise InputError("--multi, --arm_near_leaf, --held_leaf and --greenhouse must lie in "
                         "[0, 1]")
    if count < 1 or workers < 1:
        raise InputError("--count and --workers must be >= 1")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    jobs = [(seed + i, str(out), arm_near_leaf, multi, held_leaf, greenhouse,
             tuple(greenhouse_off)) for i in range(count)]
    t0 = time.time()
    counts: dict[str, int] = {}
    if workers == 1 and len(jobs) <= 25:
        results = map(_work, jobs)
    else:
        # a fresh process every 25 scenes: a long-lived one grew by ~35 MB a
        # scene (renderer and plant caches; greenhouse scenes more: one
        # process rendering 100 of them in a row was killed at 10 GB)
        pool = mp.get_context("spawn").Pool(workers, maxtasksperchild=25)
        results = pool.imap_unordered(_work, jobs)
    for r in tqdm(results, total=len(jobs), desc="rendering", unit="scene",
                  disable=not progress):
        key = r.split(" ")[0]
        counts[key] = counts.get(key, 0) + 1
        if key == "skipped":
            tqdm.write(r)
    print(f"{counts} in {time.time() - t0:.0f} s -> {out}")
    return counts
