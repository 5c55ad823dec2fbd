import json

import numpy as np
import pytest

from lmap_drake.plants.generator import (BranchPointsAtHeights, GeneratePlant, MeshSignedDistance,
                                         SaveGroundTruth)
from lmap_drake.plants.suite import PaperSuite, RandomSuite
from lmap_drake.plants.config import PlantSceneConfig

P_WC = np.array([0.5, -0.6, 0.47])


def _cfg(**kw):
    cfg = PlantSceneConfig(kind="procedural")
    for k, v in kw.items():
        setattr(cfg, k, v)
    return cfg


def test_deterministic():
    a, b = GeneratePlant(_cfg(), P_WC), GeneratePlant(_cfg(), P_WC)
    np.testing.assert_array_equal(a.leaf_rest_W, b.leaf_rest_W)
    np.testing.assert_array_equal(a.fruit_mesh_W.vertices, b.fruit_mesh_W.vertices)
    assert a.leaf_swing_deg == b.leaf_swing_deg


def test_random_suite_deterministic_by_seed():
    a, b, c = RandomSuite(3, seed=5), RandomSuite(3, seed=5), RandomSuite(3, seed=6)
    assert [x.fruit.size for x in a.values()] == [x.fruit.size for x in b.values()]
    assert [x.fruit.size for x in a.values()] != [x.fruit.size for x in c.values()]


def test_fruit_watertight_with_claimed_volume_and_leaf_clear():
    m = GeneratePlant(_cfg(), P_WC)
    assert m.fruit_mesh_W.is_watertight
    assert m.fruit_mesh_W.volume == pytest.approx(m.fruit_volume, rel=1e-9)
    # independent check: the volume of a voxelised fill of the mesh
    lo, hi = m.fruit_mesh_W.bounds
    g = np.stack(np.meshgrid(*[np.arange(lo[i], hi[i], 0.002) for i in range(3)],
                             indexing="ij"), -1).reshape(-1, 3)
    inside = MeshSignedDistance(m.fruit_mesh_W, g) < 0
    assert inside.sum() * 0.002 ** 3 == pytest.approx(m.fruit_volume, rel=0.08)
    assert MeshSignedDistance(m.fruit_mesh_W, m.leaf_rest_W).min() > 0.003
    assert 500 <= len(m.leaf_tets) <= 1500
    np.testing.assert_allclose(np.linalg.norm(m.peduncle_axis_W), 1.0)


def test_occlusion_tracks_target():
    heavy = GeneratePlant(_cfg(occlusion=0.85), P_WC)
    partial = GeneratePlant(_cfg(occlusion=0.5), P_WC)
    assert partial.occlusion_predicted == pytest.approx(0.5, abs=0.05)
    assert heavy.occlusion_predicted > partial.occlusion_predicted + 0.2


def test_paper_suite_names_and_ground_truth(tmp_path):
    suite = PaperSuite()
    assert len(suite) == 12
    assert "small_leaf_thin_branch_round_red_heavy" in suite
    m = GeneratePlant(suite["large_leaf_thick_branch_round_yellow_partial"], P_WC)
    files = SaveGroundTruth(m, tmp_path)
    gt = json.loads((tmp_path / "ground_truth.json").read_text())
    assert set(files) == {"ground_truth.json", "fruit_W.obj", "leaf_rest_W.obj"}
    assert gt["fruit_volume_m3"] == pytest.approx(m.fruit_volume)
    assert np.allclose(gt["branch_axis_W"], [0, 0, 1])


def test_suite_leaf_meshes_have_no_degenerate_tets():
    from lmap_drake.plants.leaf import TetVolumes
    for name in ("small_leaf_thin_branch_round_red_heavy",
                 "large_leaf_thick_branch_round_red_heavy"):
        m = GeneratePlant(PaperSuite()[name], P_WC)
        v = TetVolumes(m.leaf_rest_W, m.leaf_tets)
        assert v.min() > 1e-3 * np.median(v), name


def _horizontal_gap_to_branch_axis(m) -> np.ndarray:
    V = np.asarray(m.fruit_mesh_W.vertices)
    b = BranchPointsAtHeights(m.branch_points_W, V[:, 2])
    return np.linalg.norm(V[:, :2] - b[:, :2], axis=1)


@pytest.mark.parametrize("lean, tilt", [(0.0, 10.0), (0.0, 25.0), (35.0, 10.0)])
def test_fruit_placed_at_the_configured_gap_from_the_branch(lean, tilt):
    cfg = _cfg()
    cfg.fruit.lean_deg, cfg.fruit.tilt_deg = lean, tilt
    m = GeneratePlant(cfg, P_WC)
    gap = _horizontal_gap_to_branch_axis(m).min() - cfg.branch.radius
    # As close as the configured gap allows, never closer (tilted fruits too).
    assert gap == pytest.approx(cfg.fruit.gap_to_branch, abs=5e-4)


def test_lean_turns_the_fruit_top_toward_the_branch():
    tops = {}
    for lean in (0.0, 35.0):
        cfg = _cfg()
        cfg.fruit.lean_deg = lean
        m = GeneratePlant(cfg, P_WC)
        top = m.stalk_W[0]
        b = BranchPointsAtHeights(m.branch_points_W, top[2])[0]
        tops[lean] = (np.linalg.norm(top[:2] - b[:2]), m.peduncle_axis_W)
    assert tops[35.0][0] < tops[0.0][0] - 0.01          # top > 1 cm closer to the stem
    tilt = np.degrees(np.arccos(tops[35.0][1][2]))
    assert 25.0 < tilt < 45.0                            # 35 deg lean (+-10 deg own tilt)


def test_curved_procedural_peduncle_joins_fruit_and_branch():
    """``fruit.peduncle_curved``: the wide family's curved stalk is in the
    plant (labelled branch, like a file fruit's) from the cavity to the
    branch; the default keeps the straight stalk and no peduncle mesh."""
    plain = GeneratePlant(_cfg(), P_WC)
    assert plain.peduncle_mesh_W is None
    cfg = _cfg()
    f = cfg.fruit
    f.peduncle_curved, f.peduncle_length, f.peduncle_angle_deg = True, 0.05, 45.0
    f.dimple, f.cavity_offset_deg = 0.3, 12.0
    m = GeneratePlant(cfg, P_WC)
    ped = m.peduncle_mesh_W
    assert ped is not None and ped.is_watertight
    # It starts at the fruit and its far end is where the stalk to the branch starts.
    d_fruit = MeshSignedDistance(m.fruit_mesh_W, ped.vertices)
    assert np.abs(d_fruit).min() < 0.006
    np.testing.assert_allclose(m.stalk_W[0], m.peduncle_tip_W)
    assert np.linalg.norm(ped.vertices - m.peduncle_tip_W, axis=1).min() < 0.006
    # The tube rises along the fruit axis and bends sideways: its far end is
    # above the fruit top and off the axis line through the fruit centre.
    rel = m.peduncle_tip_W - m.fruit_center_W
    along = rel @ m.peduncle_axis_W
    side = np.linalg.norm(rel - along * m.peduncle_axis_W)
    top = (m.fruit_mesh_W.vertices - m.fruit_center_W) @ m.peduncle_axis_W
    assert along > top.max() + 0.01 and side > 0.015, (along, top.max(), side)
