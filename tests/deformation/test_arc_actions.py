"""Hinge arcs: the action's geometry, the rigid handle motion in the
deformation graph, and the petiole terms of the planner."""
import numpy as np
import pytest

from lmap_drake.deformation.action import (ARC_DIRECTION_BASE, Action, AxisAngleMatrix,
                                           HingeAxes, MakeArcActions)
from lmap_drake.deformation.predict import HandleDisplacements, PredictDeformations
from lmap_drake.deformation.synthetic import OvateLeaf
from lmap_drake.planning.hazard import HazardMeasures
from lmap_drake.planning.attachment import EstimateHinge
from lmap_drake.planning.energy import HingeRotationDeg, PetioleBendingEnergy
from tests.deformation.leaf_fixtures import TEST_CONFIG

# Gripper at the leaf tip: approach along +x (toward the branch), pads
# closing along z (the leaf normal).
R_GRASP = np.column_stack([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])


def test_arc_geometry():
    pivot, p = np.array([0.0, 0.0, 0.0]), np.array([0.1, 0.0, 0.0])
    a = Action(p, R_GRASP, family="arc", pivot_W=pivot, axis_W=[0, -2.0, 0],
               angle=np.deg2rad(90), direction_id=ARC_DIRECTION_BASE)
    # A quarter turn about -y lifts the tip from +x to +z, the gripper turning with it.
    assert np.allclose(a.dp_W, [-0.1, 0.0, 0.1], atol=1e-12)
    assert np.allclose(a.R_WG_end, AxisAngleMatrix([0, -1, 0], np.pi / 2) @ R_GRASP)
    assert np.isclose(a.path_length, 0.1 * np.pi / 2)
    poses = a.Poses(0.01)
    assert np.allclose(poses[-1][0], p + a.dp_W) and np.allclose(poses[-1][1], a.R_WG_end)
    # Every pose keeps the distance to the pivot, and they are <= 1 cm apart.
    pts = np.array([q for q, _ in poses])
    assert np.allclose(np.linalg.norm(pts - pivot, axis=1), 0.1)
    assert np.linalg.norm(np.diff(np.vstack([p, pts]), axis=0), axis=1).max() <= 0.0100001
    assert "arc 90 deg" in a.Describe()
    # A pull is unchanged: straight, no rotation.
    b = Action(p, R_GRASP, [0.0, 0.0, 0.04])
    assert np.allclose(b.R_delta, np.eye(3)) and np.isclose(b.path_length, 0.04)
    assert np.allclose(b.Poses(0.01)[-1][0], p + [0, 0, 0.04])
    with pytest.raises(ValueError, match="pivot_W"):
        Action(p, R_GRASP, family="arc", axis_W=[0, 0, 1], angle=0.1)
    with pytest.raises(ValueError, match="family"):
        Action(p, R_GRASP, [0, 0, 0.01], family="screw")


def test_hinge_axes_are_perpendicular_and_spread():
    pivot, p = np.array([0.5, 0.0, 0.4]), np.array([0.58, 0.05, 0.35])
    axes = HingeAxes(p, pivot, 8)
    r = (p - pivot) / np.linalg.norm(p - pivot)
    assert np.allclose(axes @ r, 0.0) and np.allclose(np.linalg.norm(axes, axis=1), 1.0)
    assert abs(axes[0, 2]) < 1e-12                    # axis 0 horizontal: lifts / lowers
    assert np.allclose(axes[4], -axes[0])             # both senses
    acts = MakeArcActions(p, R_GRASP, pivot, axes, [0.3, 0.6], grasp_id=4)
    assert len(acts) == 16 and acts[3].direction_id == ARC_DIRECTION_BASE + 1
    assert acts[3].grasp_id == 4 and np.isclose(acts[3].angle, 0.6)


def test_handle_moves_rigidly_with_the_gripper():
    p = np.array([0.1, 0.0, 0.0])
    a = Action(p, R_GRASP, family="arc", pivot_W=np.zeros(3), axis_W=[0, 0, 1], angle=0.7)
    handle = p + np.random.default_rng(0).normal(scale=0.01, size=(9, 3))
    moved = handle + HandleDisplacements(handle, [a])[0]
    # Distances within the handle and to the pivot are kept (a rotation about it).
    d0 = np.linalg.norm(handle[:, None] - handle[None], axis=2)
    d1 = np.linalg.norm(moved[:, None] - moved[None], axis=2)
    assert np.allclose(d0, d1)
    assert np.allclose(np.linalg.norm(moved, axis=1), np.linalg.norm(handle, axis=1))
    pull = Action(p, R_GRASP, [0.0, 0.02, 0.0])
    assert np.allclose(HandleDisplacements(handle, [pull])[0], [0.0, 0.02, 0.0])


def test_an_arc_about_the_attachment_deforms_the_leaf_less_than_a_pull():
    """Swinging the leaf about where it joins the branch is nearly rigid
    for the graph (low ARAP energy, the grasp's distance to the hinge kept),
    while a pull of the same chord away from the branch stretches it."""
    leaf, branch = OvateLeaf()
    hinge = EstimateHinge(leaf, branch)
    assert np.linalg.norm(hinge[:2]) < 0.01          # on the branch axis, at the petiole
    p = leaf[np.argmax(leaf[:, 0])] - [0.01, 0, 0]
    arc = MakeArcActions(p, R_GRASP, hinge, HingeAxes(p, hinge, 4)[:1], [np.deg2rad(30)])[0]
    away = Action(p, R_GRASP, arc.distance * (p - hinge) / np.linalg.norm(p - hinge))
    side = Action(p, R_GRASP, arc.dp_W)               # the arc's chord as a straight pull
    preds = PredictDeformations(leaf, branch, [arc, away, side], TEST_CONFIG)
    e_arc, e_away, e_side = (x.energy for x in preds)
    assert e_arc < 0.2 * e_side < e_away
    haz = HazardMeasures([arc, away, side], preds, hinge)
    assert abs(haz[0]["tether_elongation_m"]) < 1e-9
    assert haz[1]["tether_elongation_m"] > 0.9 * arc.distance
    assert haz[1]["petiole_stretch"] > haz[0]["petiole_stretch"]


def test_petiole_bending_term():
    h = np.zeros(3)
    assert np.isclose(HingeRotationDeg(h, [0.1, 0, 0], [0, 0.1, 0]), 90.0)
    assert np.isnan(HingeRotationDeg(None, [0.1, 0, 0], [0, 0.1, 0]))
    assert PetioleBendingEnergy(float("nan"), 1e-7) == 0.0
    assert np.isclose(PetioleBendingEnergy(60.0, 3e-7), 3e-7 * (np.pi / 3) ** 2)
    assert PetioleBendingEnergy(60.0, 0.0) == 0.0


def test_a_grasp_the_graph_cannot_model_is_reported_not_fatal():
    """A leaf piece seen apart from the rest (not connected to the branch):
    with ``skip_unmodelled`` its actions get an UnmodelledGrasp naming why,
    the other grasps are predicted; without it, or when no grasp can be
    modelled, it raises."""
    from lmap_drake.deformation.action import DeformationError
    from lmap_drake.deformation.predict import UnmodelledGrasp
    from lmap_drake.systems.deformation import DeformationPrediction
    from lmap_drake.types import SceneEstimate, SemanticScene
    leaf, branch = OvateLeaf()
    g = np.arange(0.0, 0.02, 0.0015)
    island = np.c_[0.3 + np.repeat(g, len(g)), 0.2 + np.tile(g, len(g)), np.zeros(len(g) ** 2)]
    pts = np.vstack([leaf, island])
    ok = Action(leaf[np.argmax(leaf[:, 0])] - [0.01, 0, 0], R_GRASP, [0, 0, 0.02])
    bad = Action(island.mean(0), R_GRASP, [0, 0, 0.02])
    preds = PredictDeformations(pts, branch, [ok, bad], TEST_CONFIG, skip_unmodelled=True)
    assert np.isfinite(preds[0].energy)
    assert isinstance(preds[1], UnmodelledGrasp) and "no path to a fixed" in preds[1].message
    with pytest.raises(DeformationError):
        PredictDeformations(pts, branch, [ok, bad], TEST_CONFIG)
    with pytest.raises(DeformationError):
        PredictDeformations(pts, branch, [bad], TEST_CONFIG, skip_unmodelled=True)
    system = DeformationPrediction(TEST_CONFIG, dense=False)
    scene = SceneEstimate(semantic=SemanticScene(leaf_points_W=pts, branch_points_W=branch))
    out = system.Predict(scene, [ok, bad])
    assert np.isfinite(out[0].energy) and isinstance(out[1], UnmodelledGrasp)


def test_a_speck_labelled_leaf_near_the_branch_does_not_take_the_petiole():
    """Petiole unseen, and a few points labelled leaf near the branch away
    from the blade: the virtual petiole and the hinge go to the blade."""
    from lmap_drake.deformation.graph import MainLeafComponent
    from lmap_drake.planning.attachment import AttachLeaf
    from lmap_drake.deformation.config import DeformationConfig
    from lmap_drake.types import SceneEstimate, SemanticScene
    leaf, branch = OvateLeaf()
    blade = leaf[leaf[:, 0] > 0.035]                 # petiole unseen: blade from 3.5 cm
    g = np.arange(0.0, 0.006, 0.0015)
    speck = np.c_[0.02 + np.repeat(g, len(g)), np.zeros(len(g) ** 2), -0.06 + np.tile(g, len(g))]
    pts = np.vstack([blade, speck])
    cfg = DeformationConfig()
    mask = MainLeafComponent(pts, cfg)
    assert mask[:len(blade)].all() and not mask[len(blade):].any()
    scene = SceneEstimate(semantic=SemanticScene(leaf_points_W=pts, branch_points_W=branch))
    attached, msg = AttachLeaf(scene, cfg)
    assert "virtual petiole" in msg
    line = attached.leaf_attachment_W
    assert abs(line[:, 2]).max() < 0.01              # from the blade's base, not from the speck
    hinge = EstimateHinge(pts, branch, cfg)
    assert abs(hinge[2]) < 0.01 and np.linalg.norm(hinge[:2]) < 0.01


def test_a_blade_hung_by_a_virtual_petiole_is_tied_to_the_branch_in_the_graph():
    """Petiole unseen and the blade 2-4 cm from the stem, wherever it lies
    on the voxel grid: with the virtual petiole the graph ties the blade
    to a fixed (branch) node, so its grasps can be modelled. (Started one
    step from the blade's nearest point, the petiole's first node could
    miss the blade's: 2 of these 40 placements left the blade hanging from
    nothing.)"""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from lmap_drake.deformation.graph import BuildLeafGraph
    from lmap_drake.planning.attachment import AttachLeaf
    from lmap_drake.deformation.config import DeformationConfig
    from lmap_drake.types import SceneEstimate, SemanticScene
    leaf, branch = OvateLeaf()
    cfg = DeformationConfig()
    rng = np.random.default_rng(3)
    petioles = 0
    for _ in range(40):
        gap = rng.uniform(0.02, 0.04)
        blade = leaf[leaf[:, 0] > gap]
        shift = rng.uniform(0, cfg.voxel_size, 3)      # the blade anywhere on the voxel grid
        scene = SceneEstimate(semantic=SemanticScene(leaf_points_W=blade + shift,
                                                     branch_points_W=branch + shift))
        attached, msg = AttachLeaf(scene, cfg)
        petioles += "virtual petiole" in msg
        g = BuildLeafGraph(np.vstack([blade + shift,
                                      np.reshape(attached.leaf_attachment_W, (-1, 3))]),
                           branch + shift, cfg)
        n = len(g.nodes_W)
        adj = coo_matrix((np.ones(len(g.edges)), (g.edges[:, 0], g.edges[:, 1])), shape=(n, n))
        _, label = connected_components(adj, directed=False)
        blade_label = np.bincount(label[:g.num_leaf]).argmax()
        assert blade_label in set(label[g.num_leaf:])
    assert petioles >= 30


def test_a_virtual_petiole_whose_chain_of_centroids_breaks_is_thickened():
    """The blade turned anywhere and 2-5 cm from its stem (40 placements of
    a random stream; on this machine its 23rd is one where a one-line
    petiole's voxel centroids lie beyond the edge radius of each other and
    the blade hung from nothing): AttachLeaf checks the graph and thickens
    the petiole, so every blade hangs from the branch."""
    from lmap_drake.planning.attachment import AttachLeaf, HangsFromBranch
    from lmap_drake.deformation.config import DeformationConfig
    from lmap_drake.types import SceneEstimate, SemanticScene
    leaf, branch = OvateLeaf()
    cfg = DeformationConfig()
    rng = np.random.default_rng(7)
    for k in range(140):
        gap = rng.uniform(0.02, 0.05)
        R = np.linalg.qr(rng.normal(size=(3, 3)))[0] if rng.random() < 0.5 else np.eye(3)
        shift = rng.uniform(0, 0.05, 3)
        if k < 100:
            continue
        blade, br = leaf[leaf[:, 0] > gap] @ R.T + shift, branch @ R.T + shift
        scene = SceneEstimate(semantic=SemanticScene(leaf_points_W=blade, branch_points_W=br))
        attached, msg = AttachLeaf(scene, cfg)
        assert "virtual petiole" in msg
        assert HangsFromBranch(blade, np.reshape(attached.leaf_attachment_W, (-1, 3)), br, cfg)


def test_twist_turns_the_blade_about_the_attachment_grasp_line():
    """A twist keeps the grasp point and turns the gripper about the line
    from the hinge through it; the graph turns the blade about that line
    (the leaf's far side moves, the line's points do not), at less energy
    than pulling the grasp the same arc length sideways."""
    from lmap_drake.deformation.action import TWIST_DIRECTION_BASE, MakeTwistActions
    leaf, branch = OvateLeaf()
    hinge = EstimateHinge(leaf, branch)
    p = leaf[np.argmax(leaf[:, 0])] - [0.01, 0, 0]
    plus, minus = MakeTwistActions(p, R_GRASP, hinge, [np.deg2rad(60)], grasp_id=3)
    assert (plus.direction_id, minus.direction_id) == (TWIST_DIRECTION_BASE,
                                                       TWIST_DIRECTION_BASE + 1)
    assert plus.family == "twist" and plus.grasp_id == 3
    assert np.allclose(plus.dp_W, 0, atol=1e-12) and plus.path_length < 1e-12
    assert np.allclose(plus.R_delta @ minus.R_delta, np.eye(3), atol=1e-12)
    line = (p - hinge) / np.linalg.norm(p - hinge)
    assert np.allclose(plus.R_delta @ line, line)        # the axis is the line itself
    assert plus.Describe() == "twist 60 deg" and len(plus.Poses()) >= 12   # <= 5 deg apart
    assert HingeRotationDeg(hinge, p, p + plus.dp_W) < 1e-6
    side = Action(p, R_GRASP, 0.02 * np.cross(line, [0, 0, 1.0]))
    preds = PredictDeformations(leaf, branch, [plus, minus, side], TEST_CONFIG)
    moved = np.linalg.norm(np.asarray(preds[0].leaf_points_W) - leaf, axis=1)
    # far from the line the blade moves (up to cm), on the line it barely does
    off = np.linalg.norm(np.cross(leaf - hinge, line), axis=1)
    assert moved[off > 0.02].max() > 0.01
    assert np.median(moved[off < 0.003]) < 0.3 * np.median(moved[off > 0.02])
    assert preds[0].energy > 0 and preds[1].energy > 0


def test_equivalent_turn_counts_twist_by_the_torsion_ratio():
    from lmap_drake.planning.continuation import HeldGrasp
    from lmap_drake.planning.energy import EquivalentTurnDeg
    from lmap_drake.planning.result import Candidate, PlanResult
    assert EquivalentTurnDeg(45.0, 0.0, 0.25) == 45.0
    assert np.isclose(EquivalentTurnDeg(0.0, np.deg2rad(60), 0.25), 30.0)
    assert np.isclose(EquivalentTurnDeg(45.0, np.deg2rad(60), 0.25), np.hypot(45, 30))
    assert np.isclose(EquivalentTurnDeg(45.0, np.deg2rad(60), 0.0), 45.0)
    assert np.isnan(EquivalentTurnDeg(float("nan"), 1.0, 0.25))
    # the held state sums the executed twists (either sense)
    p = np.array([0.1, 0.0, 0.0])
    from lmap_drake.deformation.action import MakeTwistActions
    tw = MakeTwistActions(p, R_GRASP, np.zeros(3), [np.deg2rad(30)])
    arc = MakeArcActions(p, R_GRASP, np.zeros(3), HingeAxes(p, np.zeros(3), 4)[:1], [0.5])[0]
    plans = [PlanResult("ok", "lmap", chosen=Candidate(a, 0)) for a in (arc, tw[1])]
    assert np.isclose(HeldGrasp.After(plans).twist_rad, np.deg2rad(30))


def test_motions_in_turn_compound_their_energy():
    """Two motions loading the leaf: the bound (sqrt E1 + sqrt E2)^2, never
    below their sum; equal to it when either is zero; the held state chains
    it over the executed motions."""
    from lmap_drake.planning.continuation import HeldGrasp
    from lmap_drake.planning.energy import CompoundEnergyPerNode
    from lmap_drake.planning.result import Candidate, PlanResult
    close = (lambda a, b: np.isclose(a, b, rtol=1e-9, atol=0.0))
    assert close(CompoundEnergyPerNode(0.0, 3e-7), 3e-7)
    assert close(CompoundEnergyPerNode(1e-7, 4e-7), 9e-7)
    assert CompoundEnergyPerNode(2e-7, 2e-7) >= 4e-7
    assert close(CompoundEnergyPerNode(-1.0, 1e-7), 1e-7)        # no negative energies
    p = np.array([0.1, 0.0, 0.0])
    arcs = MakeArcActions(p, R_GRASP, np.zeros(3), HingeAxes(p, np.zeros(3), 4)[:1], [0.3, 0.5])
    plans = []
    for a, e in zip(arcs, (1e-4, 4e-4)):
        c = Candidate(a, 0)
        c.arap_energy, c.num_leaf_nodes = e, 1000
        plans.append(PlanResult("ok", "lmap", chosen=c))
    assert close(HeldGrasp.After(plans).energy_per_node, 9e-7)
    assert close(HeldGrasp.After(plans[:1]).energy_per_node, 1e-7)
