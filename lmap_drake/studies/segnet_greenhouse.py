"""Randomised greenhouse renders for training the segmentation network
(``make_segnet_data.py --greenhouse F``): a random greenhouse plant
(``plants.greenhouse_suite``: 1-2 stems, 15-45 leaves; 3-stem plants and
46-60 leaves are never drawn here, they are kept for held-out evaluation),
procedural textures on (70 %) or flat colours, leaf colour variation
0.05-0.4, the greenhouse dressing (85 %) and neighbouring row (70 %), the
greenhouse light preset (60 %) or 1-3 random tinted directional lights at
the camera, the camera pose jittered (+-8 cm, +-8 deg), the camera model's
depth noise, dropout and flying pixels varied, and its exposure (+-10-35 %),
white balance (+-3-12 % per channel) and brightness gradient drawn per
scene. The neighbouring row's pixels are truth leaf / branch
(``labels.NeighbourClassMap``). Hue shifts, blur and pixel noise are added
per crop in training (``perception.training.RandomCrop``).

Each randomisation group can be switched off (``off``, for the ablation of
``studies/segnet_ablation.py``): every value is still drawn, so the same
seed gives the same plant with only that group at its plain setting.
"""
from __future__ import annotations

import numpy as np
import yaml
from pydrake.common.schema import Rotation
from pydrake.math import RollPitchYaw

from lmap_drake.plants.greenhouse_suite import (GREENHOUSE_SCENE_EXTRA, GreenhouseLights,
                                                GreenhouseSceneYaml, _RandomScene)
from lmap_drake.plants.generator import PlantGenerationError
from lmap_drake.plants.greenhouse import GenerateGreenhousePlant
from lmap_drake.scenario import LoadScenario
from lmap_drake.station.config import DefaultCameraConfig

TRAIN_MAX_STEMS = 2

# what ``off`` may name, and its plain setting:
GREENHOUSE_RANDOMISATIONS = {
    "textures": "flat colours, leaf colour variation 0.05",
    "clutter": "no greenhouse dressing, no neighbouring row",
    "lights": "the station's default light at the camera",
    "photometric": "no exposure, white balance or brightness-gradient variation",
    "camera_pose": "the default camera pose",
}
TRAIN_MAX_LEAVES = 45


def RandomDepthNoise(n, rng) -> None:
    """Draws the depth noise of a training scene (default-world and
    greenhouse scenes alike) into the camera-noise config ``n`` (in place):
    noise scaled 0.5-2x, mixed pixels, thin-structure and speckle dropout,
    the grazing-angle fade."""
    scale = rng.uniform(0.5, 2.0)
    n.depth_sigma_0 *= scale
    n.depth_sigma_z2 *= scale
    n.mixed_pixel_fraction = float(rng.uniform(0.1, 0.5))
    n.thin_dropout = float(rng.uniform(0.2, 0.8))
    n.grazing_start_deg = float(rng.uniform(65, 78))
    n.speckle_dropout = float(rng.uniform(0.0, 0.01))


def _RandomLights(rng: np.random.Generator) -> list[dict]:
    out = []
    for _ in range(int(rng.integers(1, 4))):
        d = np.array([rng.uniform(-0.8, 0.8), rng.uniform(-0.8, 0.8), 1.0])
        d /= np.linalg.norm(d)
        out.append(dict(type="directional", frame="camera", direction=d.round(3).tolist(),
                        color={"rgba": (1.0 - rng.uniform(0, 0.2, 3)).round(3).tolist() + [1.0]},
                        intensity=round(float(rng.uniform(0.35, 1.1)), 3)))
    return out


def TrainingGreenhousePlant(rng: np.random.Generator, name: str, max_draws: int = 20):
    """A random greenhouse plant of the training range (at most
    ``TRAIN_MAX_STEMS`` stems and ``TRAIN_MAX_LEAVES`` leaves) that the
    generator can build; raises PlantGenerationError after ``max_draws``."""
    p_WC = DefaultCameraConfig().X_PB.GetDeterministicValue().translation()
    for _ in range(max_draws):
        cfg = _RandomScene(rng, name)
        g = cfg.greenhouse
        g.num_stems = min(g.num_stems, TRAIN_MAX_STEMS)
        g.num_leaves = int(rng.integers(15, TRAIN_MAX_LEAVES + 1))
        for f in g.fruits:
            f.stem = min(f.stem, g.num_stems - 1)
        g.textures = bool(rng.random() < 0.7)
        g.leaf_color_variation = float(rng.uniform(0.05, 0.4))
        g.dressing = bool(rng.random() < 0.85)
        g.neighbour_row = bool(g.dressing and rng.random() < 0.8)
        try:
            GenerateGreenhousePlant(cfg, p_WC)
        except PlantGenerationError:
            continue
        return cfg
    raise PlantGenerationError(f"no buildable greenhouse plant in {max_draws} draws")


def RandomGreenhouseRenderScenario(seed: int, off=()):
    """(Scenario, fruit_kind, {}) for greenhouse sample ``seed`` (see the
    module docstring); fruit_kind is ``green`` when every fruit is green or
    immature, else ``mixed``. ``off``: names of ``GREENHOUSE_RANDOMISATIONS``
    left at their plain setting (ValueError for an unknown name)."""
    off = set(off)
    if off - set(GREENHOUSE_RANDOMISATIONS):
        raise ValueError(f"unknown randomisation(s) {sorted(off - set(GREENHOUSE_RANDOMISATIONS))}"
                         f"; known: {', '.join(GREENHOUSE_RANDOMISATIONS)}")
    rng = np.random.default_rng([seed, 5])
    cfg = TrainingGreenhousePlant(rng, f"gh_train_{seed}")
    g = cfg.greenhouse
    if "textures" in off:
        g.textures, g.leaf_color_variation = False, 0.05
    if "clutter" in off:
        g.dressing, g.neighbour_row = False, False
    lights = GreenhouseLights(rng) if rng.random() < 0.6 else _RandomLights(rng)
    text = (f"plant_scene:\n" + "".join(f"  {line}\n" for line in
                                         GreenhouseSceneYaml(cfg).splitlines())
            + GREENHOUSE_SCENE_EXTRA
            + ("" if "lights" in off else
               yaml.safe_dump({"lights": lights}, sort_keys=False, default_flow_style=None)))
    s = LoadScenario(scenario_text=text)
    s.random_seed = int(seed)
    cam = s.cameras["camera0"]
    X = cam.X_PB.GetDeterministicValue()
    rpy = RollPitchYaw(X.rotation()).vector() + np.radians(rng.uniform(-8, 8, 3))
    p = X.translation() + rng.uniform([-0.08, -0.1, -0.08], [0.08, 0.1, 0.08])
    if "camera_pose" not in off:
        cam.X_PB.translation = p
        cam.X_PB.rotation = Rotation(RollPitchYaw(rpy))
    q = np.asarray(s.robot.initial_q) + np.concatenate([rng.uniform(-0.25, 0.25, 3), np.zeros(3)])
    s.robot.initial_q = [float(x) for x in q]
    n = s.camera_noise
    n.seed_offset = int(rng.integers(1, 1_000_000))
    RandomDepthNoise(n, rng)
    photometric = (float(rng.uniform(0.1, 0.35)), float(rng.uniform(0.03, 0.12)),
                   float(rng.uniform(0.05, 0.2)))
    if "photometric" in off:
        photometric = (0.0, 0.0, 0.0)
    n.exposure_variation, n.white_balance_variation, n.illumination_gradient = photometric
    colors = {f.color for f in cfg.greenhouse.fruits}
    kind = "green" if colors <= {"green", "immature"} else "mixed"
    return s, kind, {}
