"""Scenario suites: the 12 paper-like plant scenarios and seeded random
ones, as YAML text loadable by ``LoadScenario``.

Paper (Sec. IV-A): two artificial leaves (small with a thin branch, large
with a thick branch), three peppers (shapes and colours: round, striped,
red and yellow) and two occlusion conditions.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from pydrake.common.yaml import yaml_dump_typed

from lmap_drake.errors import InputError
from lmap_drake.paths import DIAGRAMS_DIR
from lmap_drake.plants.fruit_mesh import FruitMeshFolder, LoadFruitMesh
from lmap_drake.plants.config import FruitConfig, MultiFruitConfig, PlantSceneConfig
from lmap_drake.plants.greenhouse_suite import (GreenhouseSuite, GreenhouseSuiteYaml,
                                                RandomGreenhouseSuite)
from lmap_drake.plants.pepper import SamplePepperShape
from lmap_drake.scenario import IsEmptyOverride
from lmap_drake.station.config import DefaultCameraConfig
from pydrake.geometry import Rgba

LEAVES = {
    "small_leaf_thin_branch": dict(leaf=dict(length=0.11, width=0.065, shape="ovate"),
                                   branch=dict(radius=0.005)),
    "large_leaf_thick_branch": dict(leaf=dict(length=0.14, width=0.08, shape="elliptic"),
                                    branch=dict(radius=0.010)),
}
PEPPERS = {
    "round_red": dict(variant="blocky", size=[0.075, 0.075, 0.08], lobes=4,
                      squareness=2.4, color=(0.75, 0.05, 0.05), stripes=0),
    "striped_red": dict(variant="elongated", size=[0.065, 0.065, 0.10], lobes=3,
                        squareness=2.2, cone=0.1, color=(0.8, 0.08, 0.05), stripes=4),
    "round_yellow": dict(variant="conical", size=[0.075, 0.07, 0.09], lobes=4,
                         squareness=2.3, cone=0.3, color=(0.95, 0.75, 0.05), stripes=0),
}
OCCLUSIONS = {"heavy": 0.85, "partial": 0.55}


def _fruit(spec: dict) -> FruitConfig:
    f = FruitConfig()
    for k, v in spec.items():
        if k == "color":
            f.color = Rgba(*v, 1.0)
            f.stripe_color = Rgba(*(0.7 * np.asarray(v)), 1.0)
        else:
            setattr(f, k, v)
    return f


def _PlantSceneYaml(cfg: PlantSceneConfig) -> str:
    """``cfg`` as YAML, only what differs from the defaults (a multi plant's
    fruits each against ``MultiFruitConfig()``: Drake's loader builds list
    items from their type's defaults)."""
    if cfg.kind != "multi":
        return yaml_dump_typed(cfg, schema=PlantSceneConfig, defaults=PlantSceneConfig())
    import copy

    import yaml

    plain = copy.deepcopy(cfg)
    plain.multi.fruits = PlantSceneConfig().multi.fruits
    data = yaml.safe_load(yaml_dump_typed(plain, schema=PlantSceneConfig,
                                          defaults=PlantSceneConfig())) or {}
    if yaml_dump_typed(cfg, schema=PlantSceneConfig) != yaml_dump_typed(plain,
                                                                       schema=PlantSceneConfig):
        data.setdefault("multi", {})["fruits"] = [
            yaml.safe_load(yaml_dump_typed(f, schema=MultiFruitConfig,
                                           defaults=MultiFruitConfig())) or {}
            for f in cfg.multi.fruits]
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=96)


def PaperSuite() -> dict[str, PlantSceneConfig]:
    """The 12 named paper-like plant scenes."""
    out = {}
    for leaf_name, leaf_spec in LEAVES.items():
        for pepper_name, pepper_spec in PEPPERS.items():
            for occ_name, occ in OCCLUSIONS.items():
                cfg = PlantSceneConfig(kind="procedural", occlusion=occ)
                cfg.name = f"{leaf_name}_{pepper_name}_{occ_name}"
                for k, v in leaf_spec["leaf"].items():
                    setattr(cfg.leaf, k, v)
                for k, v in leaf_spec["branch"].items():
                    setattr(cfg.branch, k, v)
                cfg.fruit = _fruit(pepper_spec)
                out[cfg.name] = cfg
    return out


def RandomSuite(n: int, seed: int, max_draws: int = 20, scenario_text: str = "{}",
                on_scene=None, fruit_meshes=()) -> dict[str, PlantSceneConfig]:
    """``n`` random plant scenes from ``seed`` (deterministic). A draw the
    plant generator cannot build as requested (e.g. a small leaf that cannot
    hide the drawn occlusion) is replaced by the next draw. ``scenario_text``
    (YAML overrides every episode applies after the scene, e.g. a
    ``plant_scene.fruit.mesh_file``) is applied before that check, so that
    the scenes are buildable as the episodes will run them. ``on_scene()``
    is called after each scene is drawn (a progress bar: every draw is built
    by the plant generator, 0.3-1 s). ``fruit_meshes`` ((fruit file,
    peduncle file or "") pairs, e.g. ``FruitMeshFolder(dir).values()``):
    each scene's pepper is one of them, drawn with the scene (its colour and
    tilt as drawn), instead of a procedural one."""
    draw = _WithFileFruits(_RandomScene, fruit_meshes)
    return _BuildableDraws(n, seed, draw, "random", max_draws, scenario_text, on_scene)


def _WithFileFruits(draw, fruit_meshes):
    """``draw(rng)`` whose fruits' ``mesh_file`` / ``peduncle_file`` are then
    drawn from ``fruit_meshes`` (unchanged when there are none, so a seed
    gives the same procedural suite as before)."""
    meshes = [(str(f), str(p or "")) for f, p in fruit_meshes]
    if not meshes:
        return draw

    def with_files(rng):
        cfg = draw(rng)
        fruits = [f.fruit for f in cfg.multi.fruits] if cfg.kind == "multi" else [cfg.fruit]
        for fr in fruits:
            fr.mesh_file, fr.peduncle_file = meshes[int(rng.integers(len(meshes)))]
        return cfg
    return with_files


class SuiteError(InputError, ValueError):
    """No buildable scene in a random suite's draws (the message says why;
    bad input, exit code 2: the scene count, seed and overrides asked for
    cannot be built)."""


def _BuildableDraws(n: int, seed: int, draw, prefix: str, max_draws: int,
                    scenario_text: str = "{}", on_scene=None) -> dict[str, PlantSceneConfig]:
    """``n`` scenes ``draw(rng)`` named ``<prefix>_<seed>_<i>``, each the
    first buildable one (with ``scenario_text`` applied) of at most
    ``max_draws`` draws. Raises SuiteError with the generator's last reason
    when none is."""
    rng = np.random.default_rng(seed)
    out = {}
    for i in range(n):
        for _ in range(max_draws):
            cfg = draw(rng)
            why = _WhyNotBuildable(cfg, scenario_text)
            if not why:
                break
        else:
            more = ("" if IsEmptyOverride(scenario_text) else
                    f" with the overrides {' '.join(scenario_text.split())}")
            raise SuiteError(f"{prefix} suite ({n} scenes, seed {seed}): no buildable scene "
                             f"in {max_draws} draws{more}; the last: {why}")
        cfg.name = f"{prefix}_{seed}_{i:03d}"
        out[cfg.name] = cfg
        if on_scene is not None:
            on_scene()
    return out


def _WhyNotBuildable(cfg: PlantSceneConfig, scenario_text: str = "{}") -> str:
    """"" if the plant generator builds ``cfg`` as requested (its occlusion
    is reachable, the fruit hangs on the branch; several fruits: their
    leaves fit clear of each other) from camera0, after the YAML overrides
    ``scenario_text``; else the generator's reason."""
    from lmap_drake.plants.generator import PlantGenerationError
    camera = DefaultCameraConfig()
    if not IsEmptyOverride(scenario_text):
        from lmap_drake.scenario import LoadScenario
        body = "".join(f"  {line}\n" for line in _PlantSceneYaml(cfg).splitlines())
        sc = LoadScenario(scenario_text=["plant_scene:\n" + body, scenario_text])
        cfg, camera = sc.plant_scene, sc.cameras.get("camera0", camera)
    p_WC = camera.X_PB.GetDeterministicValue().translation()
    try:
        if cfg.kind == "multi":
            from lmap_drake.plants.multi_generator import GenerateMultiPlant
            GenerateMultiPlant(cfg, p_WC)
        else:
            from lmap_drake.plants.generator import GeneratePlant
            GeneratePlant(cfg, p_WC)
    except PlantGenerationError as err:
        return str(err) or type(err).__name__
    return ""


def RandomMultiSuite(n: int, seed: int, max_draws: int = 20,
                     fruit_meshes=()) -> dict[str, PlantSceneConfig]:
    """``n`` random multi-fruit plants from ``seed`` (deterministic): 2-4
    fruits of random procedural shape, colour, size (5.5-7.5 cm) and tilt,
    spread up the stem on alternating sides, each under 0-2 leaves hiding
    40-85 % of it, and up to one free leaf more (at most 6 leaves). A draw
    the generator cannot build is replaced by the next one. ``fruit_meshes``:
    every fruit's pepper drawn from these files instead (see ``RandomSuite``)."""
    return _BuildableDraws(n, seed, _WithFileFruits(_RandomMultiScene, fruit_meshes),
                           "random_multi", max_draws)


def _RandomMultiScene(rng) -> PlantSceneConfig:
    """One random multi-fruit plant drawn from ``rng``."""
    nf = int(rng.integers(2, 5))
    heights = 0.11 + np.arange(nf) * (0.27 / max(nf - 1, 1)) + rng.uniform(-0.01, 0.01, nf)
    side = float(rng.choice([-1.0, 1.0]))
    fruits = []
    for j in range(nf):
        leaves = int(rng.integers(0, 3))
        f = MultiFruitConfig(height=float(heights[j]), side=side * (-1.0) ** j,
                             occlusion=0.0 if leaves == 0 else float(rng.uniform(0.4, 0.85)),
                             num_leaves=leaves)
        _RandomPepper(rng, f.fruit)
        size = float(rng.uniform(0.055, 0.075))
        f.fruit.size = [size, size * float(rng.uniform(0.9, 1.0)),
                        size * float(rng.uniform(1.0, 1.25))]
        fruits.append(f)
    cfg = PlantSceneConfig(kind="multi")
    cfg.multi.fruits = fruits
    cfg.multi.num_leaves = int(min(6, max(2, sum(f.num_leaves for f in fruits)
                                          + int(rng.integers(0, 2)))))
    return cfg


def _RandomPepper(rng, f: FruitConfig) -> None:
    """A random procedural pepper's shape, colour and tilt into ``f``."""
    shape = SamplePepperShape(rng)
    f.variant, f.size, f.lobes = shape.variant, list(shape.size), shape.lobes
    f.lobe_depth, f.squareness, f.shoulder = shape.lobe_depth, shape.squareness, shape.shoulder
    f.taper, f.cone = shape.taper, shape.cone
    f.lobe_phase_deg = float(np.degrees(shape.lobe_phase))
    f.color = Rgba(*[(0.75, 0.05, 0.05), (0.95, 0.75, 0.05), (0.95, 0.45, 0.05),
                     (0.2, 0.5, 0.1)][int(rng.integers(4))], 1.0)
    f.stripes = int(rng.choice([0, 0, 3, 4]))
    f.tilt_deg = float(rng.uniform(0, 20))
    f.tilt_azimuth_deg = float(rng.uniform(0, 360))


def _RandomScene(rng) -> PlantSceneConfig:
    """One random plant scene drawn from ``rng``."""
    cfg = PlantSceneConfig(kind="procedural")
    _RandomPepper(rng, cfg.fruit)
    cfg.leaf.length = float(rng.uniform(0.08, 0.15))
    cfg.leaf.width = float(cfg.leaf.length * rng.uniform(0.45, 0.65))
    cfg.leaf.shape = str(rng.choice(["ovate", "elliptic"]))
    cfg.branch.radius = float(rng.uniform(0.004, 0.011))
    cfg.branch.bend = float(rng.uniform(-0.02, 0.02))
    cfg.occlusion = float(rng.uniform(0.5, 0.9))
    return cfg


def SuiteYaml(suite: dict[str, PlantSceneConfig], header: str = "", extra: str = "") -> str:
    """A scenario file: one named scenario per plant scene; ``extra`` (YAML
    of other scenario sections, top level) is added to every scene."""
    lines = [header] if header else []
    more = "".join(f"  {line}\n" for line in extra.splitlines())
    for name, cfg in suite.items():
        body = _PlantSceneYaml(cfg)
        lines.append(f"{name}:\n  plant_scene:\n" + "".join(
            f"    {line}\n" for line in body.splitlines()) + more)
    return "\n".join(lines)


# --- multi-fruit plants (plant_scene.kind: multi) ----------------------------

# What every multi-fruit scene sets besides its plant: every fruit is revealed
# in turn, and the arm stands in the aisle with the camera, 25 cm in front of
# the plant row and 10 cm along it, instead of in the row itself (the single
# plant's mount, 0.5 m beside the stem). Side shoots spread the plant along
# the row: from inside the row the arm reaches the fruits on the far side of
# the stem only through the near leaves. From the first view of the six
# scenes (scripts/plan_plant.py), 5 of the 15 fruits to reveal had no
# feasible action (every candidate refused for robot-leaf contact on the way
# to the pre-grasp, IK or self-collision); from the aisle 1 of 15.
MULTI_SCENE_EXTRA = """planner: {targets: all}
robot:
  X_WB:
    translation: [0.1, -0.25, 0.0]
    rotation: !Rpy { deg: [0.0, 0.0, 180.0] }
"""


def _multi_fruit(height, side, occlusion, leaves, pepper="round_red", size=None, **fruit):
    f = MultiFruitConfig(height=height, side=side, occlusion=occlusion, num_leaves=leaves)
    f.fruit = _fruit(PEPPERS[pepper])
    if size is not None:
        f.fruit.size = list(size)
    for k, v in fruit.items():
        setattr(f.fruit, k, v)
    return f


def MultiSuite() -> dict[str, PlantSceneConfig]:
    """Named multi-fruit plant scenes (2-4 fruits, 2-6 leaves; some fruits
    under two leaves), at the default plant position."""
    small = (0.06, 0.06, 0.07)
    scenes = {
        "three_fruits_default": dict(),
        "two_fruits_two_leaves_heavy": dict(num_leaves=3, fruits=[
            _multi_fruit(0.15, 1.0, 0.85, 2, "round_red"),
            _multi_fruit(0.28, -1.0, 0.5, 1, "round_yellow", size=(0.065, 0.06, 0.075))]),
        "two_fruits_both_double": dict(num_leaves=5, fruits=[
            _multi_fruit(0.14, -1.0, 0.75, 2, "striped_red"),
            _multi_fruit(0.27, 1.0, 0.8, 2, "round_red", size=(0.065, 0.065, 0.075))]),
        "three_fruits_partial": dict(num_leaves=3, fruits=[
            _multi_fruit(0.13, 1.0, 0.45, 1, "round_yellow", size=(0.065, 0.06, 0.075)),
            _multi_fruit(0.24, -1.0, 0.55, 1, "round_red", size=small),
            _multi_fruit(0.35, 1.0, 0.0, 0, "striped_red", size=(0.055, 0.055, 0.085))]),
        "four_fruits": dict(num_leaves=4, fruits=[
            _multi_fruit(0.11, 1.0, 0.7, 1, "round_red", size=small),
            _multi_fruit(0.19, -1.0, 0.6, 1, "round_yellow", size=small),
            _multi_fruit(0.28, 1.0, 0.5, 1, "striped_red", size=(0.055, 0.055, 0.075)),
            _multi_fruit(0.37, -1.0, 0.0, 0, "round_red", size=small)]),
        "four_fruits_six_leaves": dict(num_leaves=6, fruits=[
            _multi_fruit(0.11, -1.0, 0.85, 2, "round_red", size=small),
            _multi_fruit(0.19, 1.0, 0.6, 1, "round_yellow", size=small),
            _multi_fruit(0.28, -1.0, 0.65, 1, "round_red", size=small),
            _multi_fruit(0.37, 1.0, 0.5, 1, "striped_red", size=(0.055, 0.055, 0.075))]),
    }
    out = {}
    for name, spec in scenes.items():
        cfg = PlantSceneConfig(kind="multi")
        cfg.name = name
        for k, v in spec.items():
            setattr(cfg.multi, k, v)
        out[name] = cfg
    return out


# --- suite files (scripts/make_suite.py) -------------------------------------

def CheckedFruitMeshes(folder) -> list[tuple[Path, Path | str]]:
    """(fruit file, peduncle file or "") of every mesh of ``folder``
    (``FruitMeshFolder``), absolute; every file is loaded and checked first
    (InputError naming the file)."""
    found = FruitMeshFolder(folder)
    for f, ped in found.values():         # every file checked before any scene is drawn
        LoadFruitMesh(str(f), str(ped))
    return [(f.resolve(), Path(ped).resolve() if ped else "") for f, ped in found.values()]


def WriteSuiteFile(out=None, random: int = 0, seed: int = 0, multi: bool = False,
                   fruit_mesh_dir: str | None = None,
                   greenhouse: bool = False) -> tuple[int, Path]:
    """Writes a suite's scenario file: the 12 paper-like scenes
    (``diagrams/suite.yaml``), ``multi`` the multi-fruit plants
    (``diagrams/multi_suite.yaml``), ``random`` > 0 that many seeded random
    scenes or plants (``out/random[_multi]_N_seedS.yaml``), their peppers
    drawn from the meshes of ``fruit_mesh_dir`` when given; ``out``
    overrides the file; ``greenhouse`` the greenhouse plants
    (``diagrams/greenhouse_suite.yaml``, or ``random`` of them). The number
    of scenes and the file written."""
    if greenhouse:
        return _WriteGreenhouseSuite(out, random, seed)
    meshes, files = (), ""
    if fruit_mesh_dir:
        meshes = CheckedFruitMeshes(fruit_mesh_dir)
        files = f" --fruit_mesh_dir {fruit_mesh_dir} ({len(meshes)} meshes)"
    extra = ""
    if multi and random > 0:
        suite, extra = RandomMultiSuite(random, seed, fruit_meshes=meshes), MULTI_SCENE_EXTRA
        header = (f"# {random} random multi-fruit plants, seed {seed}: scripts/make_suite.py "
                  f"--multi --random {random} --seed {seed}{files}")
        path = Path(out or f"out/random_multi_{random}_seed{seed}.yaml")
    elif multi:
        suite, extra = MultiSuite(), MULTI_SCENE_EXTRA
        header = ("# Multi-fruit plant scenes (plant_scene.kind: multi): 2-4 fruits on side\n"
                  "# shoots, 2-6 FEM leaves, some fruits under two leaves. Generated by\n"
                  "# scripts/make_suite.py --multi; do not edit by hand. Look at them with\n"
                  "# scripts/render_multi_suite.py. Every fruit is revealed in turn\n"
                  "# (planner.targets: all); the arm stands in the aisle in front of the\n"
                  "# row (robot.X_WB), see lmap_drake/plants/suite.py.")
        path = Path(out or DIAGRAMS_DIR / "multi_suite.yaml")
    elif random > 0:
        suite = RandomSuite(random, seed, fruit_meshes=meshes)
        header = (f"# {random} random plant scenes, seed {seed}: scripts/make_suite.py "
                  f"--random {random} --seed {seed}{files}")
        path = Path(out or f"out/random_{random}_seed{seed}.yaml")
    else:
        suite = PaperSuite()
        header = ("# The 12 paper-like plant scenes (leaf/branch x pepper x occlusion).\n"
                  "# Generated by scripts/make_suite.py; do not edit by hand.")
        path = Path(out or DIAGRAMS_DIR / "suite.yaml")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(SuiteYaml(suite, header, extra))
    return len(suite), path


def _WriteGreenhouseSuite(out, random: int, seed: int) -> tuple[int, Path]:
    if random > 0:
        suite = RandomGreenhouseSuite(random, seed)
        header = (f"# {random} random greenhouse plants, seed {seed}: scripts/make_suite.py "
                  f"--greenhouse --random {random} --seed {seed}")
        path = Path(out or f"out/random_greenhouse_{random}_seed{seed}.yaml")
    else:
        suite = GreenhouseSuite()
        header = ("# Greenhouse sweet-pepper plants (plant_scene.kind: greenhouse): 1-3 stems,\n"
                  "# 15-60 leaves, FEM only near the target fruits, greenhouse dressing and\n"
                  "# lights. Generated by scripts/make_suite.py --greenhouse; do not edit by\n"
                  "# hand. See lmap_drake/plants/greenhouse_suite.py.")
        path = Path(out or DIAGRAMS_DIR / "greenhouse_suite.yaml")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(GreenhouseSuiteYaml(suite, header, seed))
    return len(suite), path
