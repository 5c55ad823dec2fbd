"""The round trip greenhouse plant -> files (``scripts/export_plant.py``) ->
``plant_scene.kind: mesh_plant``: the same fruits (centre, volume, peduncle
axis), the same leaf count, the same occluders and FEM leaves, the same
unoccluded fruit pixels; as alpha cards, every leaf cut to its outline."""
import importlib.util

import numpy as np
import pytest

from lmap_drake.paths import REPO_ROOT
from lmap_drake.plants.mesh_plant_files import LoadMeshPlantParts
from lmap_drake.plants.multi_geometry import SurfaceDistance
from lmap_drake.plants.plant_export import MidSurface
from lmap_drake.plants.plant_station import GetPlantModel, UnoccludedFruitPixels
from lmap_drake.scenario import LoadScenario

SRC = ("{plant_scene: {kind: greenhouse, greenhouse: {seed: 3, num_leaves: 16, num_stems: 1, "
       "num_random_fruits: 1, dressing: false, neighbour_row: false}}}")


def _export_main():
    spec = importlib.util.spec_from_file_location("export_plant",
                                                  REPO_ROOT / "scripts" / "export_plant.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.main


def _mesh_scenario(folder):
    return LoadScenario(scenario_text=[
        "{plant_scene: {kind: mesh_plant, mesh_plant: {folder: '%s', X_W_plant: "
        "{translation: [0.5, 0.0, 0.1]}}}}" % folder])


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    root = tmp_path_factory.mktemp("export")
    main = _export_main()
    assert main(["--out", str(root / "obj"), "--scenario_text", SRC]) == 0
    assert main(["--out", str(root / "cards"), "--scenario_text", SRC, "--cards"]) == 0
    source = LoadScenario(scenario_text=[SRC])
    return source, GetPlantModel(source), root


def test_round_trip_keeps_fruits_leaves_and_fem_leaves(exported):
    source, g, root = exported
    s = _mesh_scenario(root / "obj")
    m = GetPlantModel(s)
    assert (root / "obj" / "plant.yaml").is_file() and (root / "obj" / "export_info.json").is_file()
    assert len(m.fruits) == len(g.fruits) == 2 and m.targets == g.targets == [0]
    for a, b in zip(g.fruits, m.fruits):
        np.testing.assert_allclose(b.center_W, a.center_W, atol=1e-4)
        assert abs(b.volume / a.volume - 1) < 0.01
        assert np.degrees(np.arccos(np.clip(a.peduncle_axis_W @ b.peduncle_axis_W, -1, 1))) < 5
        assert abs(b.occlusion_predicted - a.occlusion_predicted) < 0.03
        assert b.occluders == a.occluders
    assert m.num_leaves_total == g.num_leaves_total == 16
    # the FEM leaves are the source plant's (exported first, in its leaf order)
    assert [src.split("/")[-1] for src in m.leaf_sources] == \
        [f"leaf_{j:02d}.obj" for j in range(len(g.leaves))]
    for i in m.targets:                    # each target's main occluder is FEM
        assert m.fruits[i].occluders[0] < len(m.leaves)
    for j, leaf in enumerate(m.leaves):    # every FEM leaf hides a target or is near one
        near = min(float(SurfaceDistance([m.fruits[i].mesh_W], leaf.rest_W).min())
                   for i in m.targets)
        assert any(j in m.fruits[i].occluders for i in m.targets) or \
            near <= s.plant_scene.mesh_plant.fem_radius
    assert UnoccludedFruitPixels(s) == UnoccludedFruitPixels(source)


def test_round_trip_as_alpha_cards(exported):
    _, g, root = exported
    s = _mesh_scenario(root / "cards")
    leaves = [p for p in LoadMeshPlantParts(s.plant_scene.mesh_plant) if p.kind == "leaf"]
    assert len(leaves) == g.num_leaves_total and all(p.card for p in leaves)
    for p, surf in zip(leaves, g.AllLeafSurfaces()):
        ratio = p.sheet.area / MidSurface(surf).area      # a flat card of a curved leaf
        assert 0.75 < ratio < 1.02, (p.source, ratio)
    m = GetPlantModel(s)
    assert m.fruits[0].occluders[:1] == [0] and m.leaf_sources[0].endswith("leaf_00.obj")
