"""The greenhouse pepper plant (``plant_scene.kind: greenhouse``): its model
(a ``MultiPlantModel`` whose ``leaves`` are the FEM leaves, plus static
leaves), ground truth and the check of ``plant_scene.greenhouse``. The
generator is ``greenhouse.GenerateGreenhousePlant``. World frame W, metres.

Leaf indices: the FEM leaves first (``leaves[j]``, body ``leaf_<j>``, label
``EncodeLabel(LEAF, j)``), then the static ones (index ``len(leaves) + s``
for ``static_leaves[s]``); a fruit's ``occluders`` use these indices.
"""
from __future__ import annotations

import dataclasses as dc

import numpy as np
import trimesh

from lmap_drake.config_checks import IsFiniteNumber
from lmap_drake.plants.multi import MultiConfigError, MultiPlantModel

MIN_LEAVES, MAX_LEAVES = 15, 60
MIN_STEMS, MAX_STEMS = 1, 3
MAX_FRUITS = 10
FRUIT_COLORS = {             # (body, stripe) RGB 0-1
    "red": (0.72, 0.04, 0.04), "yellow": (0.95, 0.76, 0.06), "orange": (0.95, 0.45, 0.05),
    "green": (0.18, 0.42, 0.08), "immature": (0.10, 0.28, 0.05)}


class GreenhouseConfigError(MultiConfigError):
    """A bad ``plant_scene.greenhouse`` value; ``key`` is the scenario key path."""


@dc.dataclass
class StaticLeaf:
    """A rigid leaf welded to the world: its closed surface (W, m), the
    node it grows from, its stem, the normal of its upper side, its
    colours (upper, lower side; RGBA 0-1) and the leaf coordinates (u along
    the midrib, v across, m) of the surface's vertices (None: unknown, no
    texture)."""
    surface_W: trimesh.Trimesh
    attach_W: np.ndarray
    shoot: int
    normal_W: np.ndarray
    color: tuple
    color_below: tuple
    uv: np.ndarray | None = None


@dc.dataclass
class GreenhousePlantModel(MultiPlantModel):
    """A generated greenhouse plant: ``branches`` (stems, then one shoot per
    fruit), ``fruits``, ``leaves`` (the FEM leaves), ``static_leaves``,
    ``targets`` (fruit indices), ``leaf_colors`` (per FEM leaf, RGBA) and
    ``strings_W`` (per stem, the string's two end points)."""
    static_leaves: list = dc.field(default_factory=list)
    targets: list = dc.field(default_factory=list)
    leaf_colors: list = dc.field(default_factory=list)
    strings_W: list = dc.field(default_factory=list)
    num_stems: int = 1

    @property
    def num_leaves_total(self) -> int:
        return len(self.leaves) + len(self.static_leaves)

    def LeafSurfaceAny(self, j: int) -> trimesh.Trimesh:
        """The rest surface of leaf ``j`` (FEM or static index)."""
        k = len(self.leaves)
        return self.leaves[j].Surface() if j < k else self.static_leaves[j - k].surface_W

    def AllLeafSurfaces(self) -> list:
        return [self.LeafSurfaceAny(j) for j in range(self.num_leaves_total)]

    def GroundTruthDict(self) -> dict:
        d = super().GroundTruthDict()
        d["kind"] = "greenhouse"
        d["num_stems"] = self.num_stems
        d["targets"] = list(self.targets)
        k = len(self.leaves)
        for f in d["fruits"]:
            f["target"] = f["index"] in self.targets
        for lf in d["leaves"]:
            lf["fem"] = True
        for s, lf in enumerate(self.static_leaves):
            d["leaves"].append({"index": k + s, "leaf_attach_W": lf.attach_W.tolist(),
                                "shoot": lf.shoot, "fruit": -1, "fem": False,
                                "leaf_num_vertices": int(len(lf.surface_W.vertices))})
        hides = {j: [f["index"] for f in d["fruits"] if j in f["occluders"]]
                 for j in range(self.num_leaves_total)}
        for lf in d["leaves"]:
            lf["hides_fruits"] = hides[lf["index"]]
        return d


def ValidateGreenhouseConfig(ps) -> None:
    """Checks ``plant_scene.greenhouse`` before anything is built; raises
    GreenhouseConfigError naming the key."""
    g = ps.greenhouse
    key = "plant_scene.greenhouse"

    def need(cond, path, msg):
        if not cond:
            raise GreenhouseConfigError(f"{key}.{path}", msg)

    num = IsFiniteNumber

    def rng2(name, lo, hi):
        v = getattr(g, name)
        need(len(v) == 2 and all(num(x) for x in v) and lo <= v[0] <= v[1] <= hi, name,
             f"needs [min, max] with {lo} <= min <= max <= {hi}, got {list(v)}")
    need(isinstance(g.seed, int) and g.seed >= 0, "seed", f"must be an integer >= 0, got {g.seed}")
    need(isinstance(g.num_stems, int) and MIN_STEMS <= g.num_stems <= MAX_STEMS, "num_stems",
         f"must be {MIN_STEMS} to {MAX_STEMS}, got {g.num_stems}")
    need(isinstance(g.num_leaves, int) and MIN_LEAVES <= g.num_leaves <= MAX_LEAVES,
         "num_leaves", f"must be {MIN_LEAVES} to {MAX_LEAVES}, got {g.num_leaves}")
    need(num(g.stem_length) and 0.3 <= g.stem_length <= 1.5, "stem_length",
         f"must be in [0.3, 1.5] m, got {g.stem_length}")
    need(num(g.stem_spacing) and 0.03 <= g.stem_spacing <= 0.3, "stem_spacing",
         f"must be in [0.03, 0.3] m, got {g.stem_spacing}")
    need(num(g.lean_deg) and 0 <= g.lean_deg <= 20, "lean_deg",
         f"must be in [0, 20], got {g.lean_deg}")
    rng2("leaf_length", 0.06, 0.16)       # plant_scene.leaf.length's range
    rng2("leaf_aspect", 0.25, 0.8)
    rng2("droop_deg", 5.0, 80.0)
    need(num(g.curl) and 0 <= g.curl <= 1, "curl", f"must be in [0, 1], got {g.curl}")
    need(num(g.fem_radius) and 0 <= g.fem_radius <= 0.3, "fem_radius",
         f"must be in [0, 0.3] m, got {g.fem_radius}")
    need(isinstance(g.max_fem_leaves, int) and 0 <= g.max_fem_leaves <= 8, "max_fem_leaves",
         f"must be 0 to 8, got {g.max_fem_leaves}")
    need(isinstance(g.fem_target_tets, int) and 100 <= g.fem_target_tets <= 5000,
         "fem_target_tets", f"must be 100 to 5000, got {g.fem_target_tets}")
    need(num(g.leaf_color_variation) and 0 <= g.leaf_color_variation <= 1,
         "leaf_color_variation", f"must be in [0, 1], got {g.leaf_color_variation}")
    need(isinstance(g.textures, bool), "textures", f"must be true or false, got {g.textures!r}")
    need(isinstance(g.num_random_fruits, int) and g.num_random_fruits >= 0, "num_random_fruits",
         f"must be an integer >= 0, got {g.num_random_fruits}")
    n = len(g.fruits) + g.num_random_fruits
    need(1 <= n <= MAX_FRUITS, "fruits",
         f"the plant needs 1 to {MAX_FRUITS} fruits (fruits + num_random_fruits), got {n}")
    covers = 0
    for i, f in enumerate(g.fruits):
        p = f"fruits[{i}]"
        need(isinstance(f.stem, int) and 0 <= f.stem < g.num_stems, f"{p}.stem",
             f"must be 0 to num_stems - 1 = {g.num_stems - 1}, got {f.stem}")
        need(num(f.height) and 0.1 <= f.height <= 0.85, f"{p}.height",
             f"must be in [0.1, 0.85] (fraction of stem_length), got {f.height}")
        need(num(f.azimuth_deg), f"{p}.azimuth_deg", f"must be a finite number, got {f.azimuth_deg}")
        need(f.color == "" or f.color in FRUIT_COLORS, f"{p}.color",
             f"must be empty or one of {sorted(FRUIT_COLORS)}, got {f.color!r}")
        need(isinstance(f.cover_leaves, int) and 0 <= f.cover_leaves <= 2, f"{p}.cover_leaves",
             f"must be 0, 1 or 2, got {f.cover_leaves}")
        need(num(f.occlusion) and 0 <= f.occlusion < 1, f"{p}.occlusion",
             f"must be in [0, 1), got {f.occlusion}")
        covers += f.cover_leaves
    need(covers <= g.num_leaves, "num_leaves",
         f"({g.num_leaves}) is less than the fruits' cover leaves ({covers})")
