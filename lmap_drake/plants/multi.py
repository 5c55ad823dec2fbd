"""Plants with several fruits and several leaves (``plant_scene.kind:
multi``): the model (branches, fruits, FEM leaves at rest; world frame W,
metres), its ground truth files, and the check of ``plant_scene.multi``.
The generator is ``multi_generator.GenerateMultiPlant``; distances and ray
casts between the parts are in ``multi_geometry``.
"""
from __future__ import annotations

import dataclasses as dc
import json
from pathlib import Path

import numpy as np
import trimesh

from lmap_drake.config_checks import IsFiniteNumber
from lmap_drake.plants.fruit_mesh import FruitMeshError, LoadFruitMeshOf
from lmap_drake.plants.generator import PlantGenerationError
from lmap_drake.plants.leaf import BoundaryTriangles
from lmap_drake.plants.mesh_plant_files import LoadMeshPlantParts
from lmap_drake.plants.pepper import PepperShapeOf

MAX_FRUITS, MIN_FRUITS = 4, 2
MULTI_KINDS = ("multi", "greenhouse", "mesh_plant")   # kinds with several fruits and leaves
MAX_LEAVES, MIN_LEAVES = 6, 2
OCCLUDER_MIN = 0.02        # a leaf hiding at least this fraction of a fruit is one of its occluders
FRUIT_GAP = 0.005          # m, fruit to fruit and fruit to other shoots


def NumPlantFruits(ps) -> int:
    """The fruits a ``plant_scene`` asks for: ``multi.fruits``; greenhouse:
    ``greenhouse.fruits`` plus ``num_random_fruits`` (at most: a random fruit
    that does not fit is left out); mesh_plant: its fruit parts; 1 otherwise."""
    if ps.kind == "multi":
        return len(ps.multi.fruits)
    if ps.kind == "greenhouse":
        return len(ps.greenhouse.fruits) + int(ps.greenhouse.num_random_fruits)
    if ps.kind == "mesh_plant":
        return sum(p.kind == "fruit" for p in LoadMeshPlantParts(ps.mesh_plant))
    return 1


class MultiConfigError(PlantGenerationError):
    """A bad ``plant_scene.multi`` value; ``key`` is the scenario key path."""

    def __init__(self, key: str, detail: str):
        super().__init__(f"{key} {detail}")
        self.key, self.detail = key, detail


@dc.dataclass
class Branch:
    """A stem or side shoot: centre line (K, 3) base to tip and radius (m).
    ``parent``: index of the branch it grows from (-1 for the stem)."""
    name: str
    points_W: np.ndarray
    radius: float
    parent: int = -1


@dc.dataclass
class MultiFruit:
    """One fruit (world frame, m): its mesh, pose ``X_WO`` (canonical fruit
    frame O, +z the peduncle axis), the stalk from the fruit to its shoot,
    and ``shoot`` (index into ``MultiPlantModel.branches``)."""
    mesh_W: trimesh.Trimesh
    stripe_faces: np.ndarray
    X_WO: np.ndarray
    center_W: np.ndarray
    peduncle_axis_W: np.ndarray
    peduncle_tip_W: np.ndarray
    stalk_W: np.ndarray                  # (2, 3): fruit top (or curved stalk tip) -> shoot
    volume: float
    shoot: int
    color: object = None                 # Rgba
    stripe_color: object = None
    stalk_radius: float = 0.004
    peduncle_mesh_W: trimesh.Trimesh | None = None
    fruit_file: str = ""                 # fruit.mesh_file (resolved), "" = procedural
    fruit_mesh_repairs: list = dc.field(default_factory=list)
    occlusion_requested: float = float("nan")
    occlusion_predicted: float = 0.0     # hidden fraction of the camera-visible surface, all leaves
    occlusion_clamped: bool = False
    occluders: list = dc.field(default_factory=list)   # leaf indices hiding >= OCCLUDER_MIN
    # the most of it camera0 sees with one leaf taken away entirely (the
    # others in place; 1 - hidden fraction): what one leaf's move can reveal
    one_leaf_ceiling: float = 1.0


@dc.dataclass
class MultiLeaf:
    """One FEM leaf at rest (world frame, m): vertices (N, 3), tets (T, 4),
    leaf coordinates ``uv`` (N, 2), ``fixed`` petiole-base vertices,
    ``attach_W`` the petiole base, ``shoot`` the branch index it sits on,
    ``fruit`` the fruit it was placed over (-1: a free leaf)."""
    rest_W: np.ndarray
    tets: np.ndarray
    uv: np.ndarray
    fixed: np.ndarray
    attach_W: np.ndarray
    shoot: int
    fruit: int
    midrib_W: np.ndarray
    normal_W: np.ndarray
    swing_deg: float
    reach: float

    def Surface(self) -> trimesh.Trimesh:
        return trimesh.Trimesh(self.rest_W, BoundaryTriangles(self.tets), process=False)


@dc.dataclass
class MultiPlantModel:
    """A generated multi-fruit plant (world frame, metres)."""
    branches: list[Branch]
    fruits: list[MultiFruit]
    leaves: list[MultiLeaf]
    p_WC: np.ndarray                     # camera0 position used for the occlusions

    def LeafSurface(self, i: int) -> trimesh.Trimesh:
        return self.leaves[i].Surface()

    def AllLeafSurfaces(self) -> list:
        """Every leaf's rest surface, in ground-truth leaf order."""
        return [lf.Surface() for lf in self.leaves]

    def GroundTruthDict(self) -> dict:
        return {
            "kind": "multi",
            "camera0_p_WC": self.p_WC.tolist(),
            "branches": [{"name": b.name, "points_W": b.points_W.tolist(), "radius": b.radius,
                          "parent": b.parent} for b in self.branches],
            "fruits": [{"index": i, "fruit_center_W": f.center_W.tolist(),
                        "peduncle_axis_W": f.peduncle_axis_W.tolist(),
                        "peduncle_tip_W": f.peduncle_tip_W.tolist(),
                        "fruit_volume_m3": f.volume, "X_WO": f.X_WO.tolist(),
                        "shoot": f.shoot, "stalk_W": f.stalk_W.tolist(),
                        "occlusion_requested": (None if np.isnan(f.occlusion_requested)
                                                else f.occlusion_requested),
                        "occlusion_predicted": f.occlusion_predicted,
                        "occlusion_clamped": f.occlusion_clamped,
                        "occluders": list(f.occluders),
                        "one_leaf_ceiling": f.one_leaf_ceiling,
                        "fruit_source": f.fruit_file or "procedural",
                        "fruit_mesh_repairs": list(f.fruit_mesh_repairs),
                        "own_leaves": [j for j, lf in enumerate(self.leaves) if lf.fruit == i]}
                       for i, f in enumerate(self.fruits)],
            "leaves": [{"index": j, "leaf_attach_W": lf.attach_W.tolist(), "shoot": lf.shoot,
                        "fruit": lf.fruit, "leaf_swing_deg": lf.swing_deg, "reach": lf.reach,
                        "leaf_num_vertices": int(len(lf.rest_W)),
                        "leaf_num_tets": int(len(lf.tets))}
                       for j, lf in enumerate(self.leaves)]}


def SaveMultiGroundTruth(model: MultiPlantModel, folder: str | Path) -> list[str]:
    """Writes ``ground_truth.json``, ``fruit_<i>_W.obj`` and ``leaf_<j>_rest_W.obj``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "ground_truth.json").write_text(json.dumps(model.GroundTruthDict(), indent=2))
    names = ["ground_truth.json"]
    for i, f in enumerate(model.fruits):
        f.mesh_W.export(folder / f"fruit_{i}_W.obj")
        names.append(f"fruit_{i}_W.obj")
    for j, surface in enumerate(model.AllLeafSurfaces()):
        surface.export(folder / f"leaf_{j}_rest_W.obj")
        names.append(f"leaf_{j}_rest_W.obj")
    return names


# --- validation -----------------------------------------------------------

def ValidateMultiConfig(ps) -> None:
    """Checks ``plant_scene.multi`` (``ps`` a ``PlantSceneConfig``) before
    anything is built; raises MultiConfigError naming the key."""
    m = ps.multi
    key = "plant_scene.multi"

    def need(cond, path, msg):
        if not cond:
            raise MultiConfigError(f"{key}.{path}", msg)

    num = IsFiniteNumber
    n = len(m.fruits)
    need(MIN_FRUITS <= n <= MAX_FRUITS, "fruits",
         f"needs {MIN_FRUITS} to {MAX_FRUITS} fruits, got {n}")
    need(isinstance(m.num_leaves, int) and MIN_LEAVES <= m.num_leaves <= MAX_LEAVES,
         "num_leaves", f"must be {MIN_LEAVES} to {MAX_LEAVES}, got {m.num_leaves}")
    need(num(m.shoot_radius) and 0 < m.shoot_radius <= 0.02, "shoot_radius",
         f"must be in (0, 0.02] m, got {m.shoot_radius}")
    need(num(m.leaf_gap) and 0 <= m.leaf_gap <= 0.02, "leaf_gap",
         f"must be in [0, 0.02] m, got {m.leaf_gap}")
    need(num(m.free_leaf_swing_deg) and 0 <= m.free_leaf_swing_deg <= 90,
         "free_leaf_swing_deg", f"must be in [0, 90], got {m.free_leaf_swing_deg}")
    for i, f in enumerate(m.fruits):
        p = f"fruits[{i}]"
        need(isinstance(f.num_leaves, int) and 0 <= f.num_leaves <= 2, f"{p}.num_leaves",
             f"must be 0, 1 or 2, got {f.num_leaves}")
        need(num(f.occlusion) and (0 < f.occlusion < 1 if f.num_leaves else
                                   0 <= f.occlusion < 1), f"{p}.occlusion",
             f"must be in (0, 1) for a fruit with leaves, got {f.occlusion}")
        need(num(f.height) and 0 < f.height < ps.branch.length, f"{p}.height",
             f"must be in (0, plant_scene.branch.length = {ps.branch.length}) m, got {f.height}")
        need(num(f.side) and f.side != 0, f"{p}.side", f"must be +1 or -1, got {f.side}")
        need(num(f.shoot_extra) and 0 <= f.shoot_extra <= 0.1, f"{p}.shoot_extra",
             f"must be in [0, 0.1] m, got {f.shoot_extra}")
        need(num(f.shoot_rise_deg) and 0 <= f.shoot_rise_deg <= 60, f"{p}.shoot_rise_deg",
             f"must be in [0, 60], got {f.shoot_rise_deg}")
        need(not f.fruit.peduncle_file or f.fruit.mesh_file, f"{p}.fruit.peduncle_file",
             f"needs {key}.{p}.fruit.mesh_file (the procedural pepper has its own stalk)")
        if f.fruit.mesh_file:
            FileFruit(f.fruit, f"{key}.{p}.fruit")      # checked before anything is built
        need(len(f.fruit.size) == 3 and all(num(x) and x > 0 for x in f.fruit.size),
             f"{p}.fruit.size", f"needs 3 values > 0, got {list(f.fruit.size)}")
        for name in ("tilt_deg", "tilt_azimuth_deg", "peduncle_length", "peduncle_radius"):
            v = getattr(f.fruit, name)
            need(num(v) and (v > 0 if name.startswith("ped") else True), f"{p}.fruit.{name}",
                 f"must be a finite number{' > 0' if name.startswith('ped') else ''}, got {v}")
        try:
            PepperShapeOf(f.fruit).validate()
        except ValueError as err:
            raise MultiConfigError(f"{key}.{p}.fruit", f"is not a valid pepper shape: {err}")
    own = sum(f.num_leaves for f in m.fruits)
    need(own <= m.num_leaves, "num_leaves",
         f"({m.num_leaves}) is less than the fruits' leaves (sum of fruits[*].num_leaves = {own})")


def FileFruit(fruit_cfg, key: str):
    """``LoadFruitMeshOf`` a fruit config with ``mesh_file`` set, its errors
    naming ``key`` (e.g. ``plant_scene.multi.fruits[1].fruit``) instead of
    ``plant_scene.fruit``."""
    try:
        return LoadFruitMeshOf(fruit_cfg)
    except FruitMeshError as err:
        raise MultiConfigError(err.key.replace("plant_scene.fruit", key, 1),
                               err.detail.replace("plant_scene.fruit.", key + ".")) from None
