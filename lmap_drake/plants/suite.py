"""Scenario suites: the 12 paper-like plant scenarios and seeded random
ones, as YAML text loadable by ``LoadScenario``.

Paper (Sec. IV-A): two artificial leaves (small with a thin branch, large
with a thick branch), three peppers (shapes and colours: round, striped,
red and yellow) and two occlusion conditions.
"""
from __future__ import annotations

import numpy as np
from pydrake.common.yaml import yaml_dump_typed

from lmap_drake.plants.pepper import SamplePepperShape
from lmap_drake.scenario import FruitConfig, PlantSceneConfig
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


def _Buildable(cfg: PlantSceneConfig) -> bool:
    """True if ``GeneratePlant`` builds ``cfg`` as requested from the default
    camera (its occlusion is reachable, the fruit hangs on the branch)."""
    from lmap_drake.plants.generator import GeneratePlant, PlantGenerationError
    from lmap_drake.scenario import DefaultCameraConfig
    p_WC = DefaultCameraConfig().X_PB.GetDeterministicValue().translation()
    try:
        GeneratePlant(cfg, p_WC)
    except PlantGenerationError:
        return False
    return True


def RandomSuite(n: int, seed: int, max_draws: int = 20) -> dict[str, PlantSceneConfig]:
    """``n`` random plant scenes from ``seed`` (deterministic). A draw the
    plant generator cannot build as requested (e.g. a small leaf that cannot
    hide the drawn occlusion) is replaced by the next draw."""
    rng = np.random.default_rng(seed)
    out = {}
    for i in range(n):
        for _ in range(max_draws):
            cfg = _RandomScene(rng)
            if _Buildable(cfg):
                break
        else:
            raise ValueError(f"RandomSuite({n}, {seed}): no buildable scene in {max_draws} draws")
        cfg.name = f"random_{seed}_{i:03d}"
        out[cfg.name] = cfg
    return out


def _RandomScene(rng) -> PlantSceneConfig:
    """One random plant scene drawn from ``rng``."""
    cfg = PlantSceneConfig(kind="procedural")
    shape = SamplePepperShape(rng)
    f = cfg.fruit
    f.variant, f.size, f.lobes = shape.variant, list(shape.size), shape.lobes
    f.lobe_depth, f.squareness, f.shoulder = shape.lobe_depth, shape.squareness, shape.shoulder
    f.taper, f.cone = shape.taper, shape.cone
    f.lobe_phase_deg = float(np.degrees(shape.lobe_phase))
    f.color = Rgba(*[(0.75, 0.05, 0.05), (0.95, 0.75, 0.05), (0.95, 0.45, 0.05),
                     (0.2, 0.5, 0.1)][int(rng.integers(4))], 1.0)
    f.stripes = int(rng.choice([0, 0, 3, 4]))
    f.tilt_deg = float(rng.uniform(0, 20))
    f.tilt_azimuth_deg = float(rng.uniform(0, 360))
    cfg.leaf.length = float(rng.uniform(0.08, 0.15))
    cfg.leaf.width = float(cfg.leaf.length * rng.uniform(0.45, 0.65))
    cfg.leaf.shape = str(rng.choice(["ovate", "elliptic"]))
    cfg.branch.radius = float(rng.uniform(0.004, 0.011))
    cfg.branch.bend = float(rng.uniform(-0.02, 0.02))
    cfg.occlusion = float(rng.uniform(0.5, 0.9))
    return cfg


def SuiteYaml(suite: dict[str, PlantSceneConfig], header: str = "") -> str:
    """A scenario file: one named scenario per plant scene."""
    lines = [header] if header else []
    for name, cfg in suite.items():
        body = yaml_dump_typed(cfg, schema=PlantSceneConfig, defaults=PlantSceneConfig())
        lines.append(f"{name}:\n  plant_scene:\n" + "".join(
            f"    {line}\n" for line in body.splitlines()))
    return "\n".join(lines)
