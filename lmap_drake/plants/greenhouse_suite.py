"""Greenhouse plant suites (``plant_scene.kind: greenhouse``): the named
scenes of ``diagrams/greenhouse_suite.yaml`` and seeded random greenhouse
plants (``scripts/make_suite.py --greenhouse [--random N --seed S]``), with
a greenhouse light preset per scene (``GreenhouseLights``: a warm key light
from above, a fill light at the camera and a back light through the glass,
their direction, colour and intensity varied per scene) and the camera's
exposure and white balance drawn per scene (``GreenhouseCameraNoise``)."""
from __future__ import annotations

import copy

import numpy as np
import yaml
from pydrake.common.yaml import yaml_dump_typed

from lmap_drake.errors import InputError
from lmap_drake.plants.config import GreenhouseFruitConfig, PlantSceneConfig
from lmap_drake.plants.generator import PlantGenerationError
from lmap_drake.plants.greenhouse import GenerateGreenhousePlant
from lmap_drake.plants.greenhouse_model import FRUIT_COLORS
from lmap_drake.station.config import DefaultCameraConfig

# Every greenhouse scene: every fruit revealed in turn, the arm in the aisle
# clear of the row's canopy, and segnet with the weights trained for the
# greenhouse's look (models/segnet/segnet_greenhouse.json; they lose 0.01-0.03
# IoU on the one-leaf world, whose default stays segnet.pt).
# The arm's base stands GREENHOUSE_AISLE_OFFSET in front of the row line,
# 40 cm along the row from the worked plant, as the multi-fruit suite's
# (plants.suite.MULTI_SCENE_EXTRA) stands 25 cm in front. That suite has no
# neighbouring plants; here the row's next plant stands 45 cm along it
# (greenhouse_scene.AddGreenhouseDressing), 5 cm from the base's line, and
# at 25 cm in front the base stood inside that plant's leaves: leaf tips
# reach 0.15-0.31 m from their stem (28 plants: this suite and random
# seeds 5353 and 6363), and the upper arm pushed them on nearly every
# approach (the planner refused them all for `gh_green_heavy`'s hidden
# fruit).
# 45 cm keeps the base (radius 7.5 cm) about 7 cm clear of the widest canopy
# measured, sqrt(0.45^2 + 0.05^2) - 0.075 - 0.31. See
# docs/explanation/plant-world.md ("Where the arm stands").
GREENHOUSE_AISLE_OFFSET = 0.45   # m, base in front of the row line
GREENHOUSE_SCENE_EXTRA = f"""planner: {{targets: all}}
perception: {{segnet_weights: models/segnet/segnet_greenhouse.pt}}
robot:
  X_WB:
    translation: [0.1, {-GREENHOUSE_AISLE_OFFSET}, 0.0]
    rotation: !Rpy {{ deg: [0.0, 0.0, 180.0] }}
"""


def GreenhouseLights(rng: np.random.Generator) -> list[dict]:
    """The greenhouse light preset (Drake ``LightParameter`` fields, for the
    scenario's ``lights``): key (world, from above), fill (at the camera),
    back (world, from behind the plant toward the aisle), varied by ``rng``."""
    def u(lo, hi):
        return round(float(rng.uniform(lo, hi)), 3)
    az = u(-0.8, 0.8)
    key_dir = [round(float(np.sin(az)) * 0.5, 3), round(float(np.cos(az)) * 0.5, 3), -1.0]   # down, toward +y
    warm = u(0.0, 0.12)
    return [
        dict(type="directional", frame="world", direction=key_dir,
             color={"rgba": [1.0, round(1.0 - 0.4 * warm, 3), round(1.0 - warm, 3), 1.0]},
             intensity=u(0.7, 1.0)),
        dict(type="directional", frame="camera", direction=[0.0, 0.0, 1.0],
             color={"rgba": [0.95, 0.97, 1.0, 1.0]}, intensity=u(0.35, 0.55)),
        dict(type="directional", frame="world",
             direction=[u(-0.3, 0.3), -1.0, u(-0.6, -0.2)],
             color={"rgba": [0.9, 0.95, 1.0, 1.0]}, intensity=u(0.3, 0.6))]


def _fruit(**kw) -> GreenhouseFruitConfig:
    return GreenhouseFruitConfig(**kw)


def _scene(name, seed, **g) -> PlantSceneConfig:
    cfg = PlantSceneConfig(kind="greenhouse", name=name)
    cfg.greenhouse.seed = seed
    for k, v in g.items():
        setattr(cfg.greenhouse, k, v)
    return cfg


def GreenhouseSuite() -> dict[str, PlantSceneConfig]:
    """The named greenhouse scenes: one and several targets, heavy and
    partial occlusion, green and immature fruit, two leaves over one fruit,
    a fruit behind a stem, sparse and dense plants."""
    F = _fruit
    scenes = [
        _scene("gh_one_red_heavy", 20, fruits=[F(color="red", occlusion=0.8)]),
        _scene("gh_one_yellow_partial", 2, fruits=[F(color="yellow", occlusion=0.45)]),
        _scene("gh_green_heavy", 3, fruits=[F(color="green", occlusion=0.75, height=0.4)]),
        _scene("gh_immature_partial", 4, fruits=[F(color="immature", occlusion=0.5,
                                                   height=0.45)]),
        _scene("gh_two_leaves_one_fruit", 5, fruits=[F(color="orange", cover_leaves=2,
                                                       occlusion=0.85)]),
        _scene("gh_fruit_behind_stem", 6, num_stems=1, fruits=[
            F(color="red", azimuth_deg=165.0, occlusion=0.4, height=0.35)]),
        _scene("gh_two_targets", 7, fruits=[
            F(stem=0, color="red", occlusion=0.7, height=0.3),
            F(stem=1, color="yellow", azimuth_deg=70.0, occlusion=0.5, height=0.5)]),
        _scene("gh_three_targets", 8, num_stems=3, num_leaves=40, max_fem_leaves=4, fruits=[
            F(stem=0, color="red", occlusion=0.75, height=0.3),
            F(stem=1, color="green", azimuth_deg=-20.0, occlusion=0.5, height=0.5),
            F(stem=2, color="orange", azimuth_deg=70.0, occlusion=0.6, height=0.35)],
            num_random_fruits=1),
        _scene("gh_dense_60_leaves", 23, num_stems=3, num_leaves=60, fruits=[
            F(stem=1, color="red", azimuth_deg=-30.0, occlusion=0.7)]),
        _scene("gh_sparse_15_leaves", 10, num_stems=1, num_leaves=15, num_random_fruits=1,
               fruits=[F(color="yellow", occlusion=0.6)]),
        _scene("gh_lanceolate_leaves", 11, leaf_aspect=[0.28, 0.4], fruits=[
            F(color="orange", occlusion=0.6)]),
        _scene("gh_droopy_curled", 12, droop_deg=[45.0, 75.0], curl=0.6, fruits=[
            F(color="red", occlusion=0.7, height=0.4)]),
        _scene("gh_green_two_leaves_and_red", 13, num_leaves=36, fruits=[
            F(stem=0, color="green", cover_leaves=2, occlusion=0.85, height=0.3),
            F(stem=1, color="red", azimuth_deg=80.0, occlusion=0.5, height=0.5)]),
        _scene("gh_no_cover_random_canopy", 14, num_leaves=45, fruits=[
            F(color="red", cover_leaves=0, occlusion=0.0, height=0.35, azimuth_deg=-40.0)]),
    ]
    return {c.name: c for c in scenes}


def _RandomScene(rng: np.random.Generator, name: str) -> PlantSceneConfig:
    n_stems = int(rng.integers(1, 4))
    n_targets = int(rng.integers(1, min(3, n_stems + 1) + 1))
    fruits = []
    for k in range(n_targets):
        fruits.append(GreenhouseFruitConfig(
            stem=int(rng.integers(n_stems)), height=float(rng.uniform(0.2, 0.6)),
            azimuth_deg=float(rng.uniform(-170, 170)),
            color=sorted(FRUIT_COLORS)[int(rng.integers(len(FRUIT_COLORS)))],
            cover_leaves=int(rng.choice([0, 1, 1, 2])), occlusion=float(rng.uniform(0.3, 0.85))))
    return _scene(name, int(rng.integers(0, 2**31 - 1)), num_stems=n_stems,
                  num_leaves=int(rng.integers(15, 61)), fruits=fruits,
                  num_random_fruits=int(rng.integers(0, 4)),
                  leaf_aspect=sorted(rng.uniform(0.28, 0.72, 2).tolist()),
                  droop_deg=sorted(rng.uniform(15, 70, 2).tolist()),
                  curl=float(rng.uniform(0, 0.6)),
                  max_fem_leaves=int(rng.integers(2, 5)))


class GreenhouseSuiteError(InputError, ValueError):
    """No buildable random greenhouse plant in the draws."""


def RandomGreenhouseSuite(n: int, seed: int, max_draws: int = 20) -> dict[str, PlantSceneConfig]:
    """``n`` random greenhouse plants from ``seed`` (deterministic); a draw
    the generator cannot build is replaced by the next draw (at most
    ``max_draws`` per scene)."""
    rng = np.random.default_rng(seed)
    p_WC = DefaultCameraConfig().X_PB.GetDeterministicValue().translation()
    out = {}
    for k in range(n):
        name = f"gh_random_{seed}_{k:03d}"
        for _ in range(max_draws):
            cfg = _RandomScene(rng, name)
            try:
                GenerateGreenhousePlant(cfg, p_WC)
            except PlantGenerationError:
                continue
            out[name] = cfg
            break
        else:
            raise GreenhouseSuiteError(f"--random {n} --seed {seed}: no buildable greenhouse "
                                       f"plant in {max_draws} draws for scene {k}")
    return out


def GreenhouseSceneYaml(cfg: PlantSceneConfig) -> str:
    """``cfg`` as YAML, only what differs from the defaults (each fruit
    against ``GreenhouseFruitConfig()``)."""
    plain = copy.deepcopy(cfg)
    plain.greenhouse.fruits = PlantSceneConfig().greenhouse.fruits
    data = yaml.safe_load(yaml_dump_typed(plain, schema=PlantSceneConfig,
                                          defaults=PlantSceneConfig())) or {}
    if yaml_dump_typed(cfg, schema=PlantSceneConfig) != yaml_dump_typed(
            plain, schema=PlantSceneConfig):
        data.setdefault("greenhouse", {})["fruits"] = [
            yaml.safe_load(yaml_dump_typed(f, schema=GreenhouseFruitConfig,
                                           defaults=GreenhouseFruitConfig())) or {}
            for f in cfg.greenhouse.fruits]
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=96)


def GreenhouseCameraNoise(rng: np.random.Generator) -> dict:
    """The scene's ``camera_noise`` keys: the L515 model of
    ``station.config.CameraNoiseConfig`` (on by default) with its own
    ``seed_offset``, so that every scene draws its own exposure gain,
    white balance and brightness gradient (with one seed for all, every
    scene of a suite would get the same)."""
    return {"seed_offset": int(rng.integers(1, 1_000_000))}


def GreenhouseSuiteYaml(suite: dict[str, PlantSceneConfig], header: str, seed: int = 0) -> str:
    """A scenario file: per scene its plant, ``GREENHOUSE_SCENE_EXTRA``, its
    lights (``GreenhouseLights``, drawn from ``seed`` and the scene's
    position in the suite) and its camera exposure and white balance
    (``GreenhouseCameraNoise``, likewise)."""
    lines = [header]
    for k, (name, cfg) in enumerate(suite.items()):
        lights = yaml.safe_dump({"lights": GreenhouseLights(np.random.default_rng([seed, k])),
                                 "camera_noise": GreenhouseCameraNoise(
                                     np.random.default_rng([seed, k, 1]))},
                                sort_keys=False, default_flow_style=None, width=96)
        body = "".join(f"    {line}\n" for line in GreenhouseSceneYaml(cfg).splitlines())
        more = "".join(f"  {line}\n" for line in (GREENHOUSE_SCENE_EXTRA + lights).splitlines())
        lines.append(f"{name}:\n  plant_scene:\n{body}{more}")
    return "\n".join(lines)
