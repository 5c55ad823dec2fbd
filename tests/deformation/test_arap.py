import numpy as np
import pytest
from scipy.spatial import cKDTree

from lmap_drake.deformation import (
    Action, ArapProblem, MakeActions, PredictDeformations, PullDirections)

from leaf_fixtures import R_TIP, TEST_CONFIG as CFG


def brute_energy(g, positions, rotations):
    """E = sum over both edge directions of w |e'_ij - R_i e_ij|^2 (one action)."""
    E = 0.0
    for (i, j), w in zip(g.edges, g.weights):
        e, ed = g.nodes_W[i] - g.nodes_W[j], positions[i] - positions[j]
        E += w * np.sum((ed - rotations[i] @ e) ** 2) + w * np.sum((-ed + rotations[j] @ e) ** 2)
    return E


def test_rigid_translation_of_all_constraints_is_free(tip_graph):
    _, g = tip_graph
    prob = ArapProblem(g.nodes_W, g.edges, g.weights, g.num_free)
    t = np.array([[0.03, -0.02, 0.05], [0.0, 0.0, 0.0]])
    res = prob.Solve(np.repeat(t[:, None], g.num_constrained, axis=1), 50, 1e-5)
    assert np.all(res.energy < 1e-12)
    assert np.allclose(res.displacements, t[:, None], atol=1e-10)
    assert np.allclose(res.rotations, np.eye(3), atol=1e-8)
    assert np.all(res.iterations == 1) and res.converged.all()


def test_energy_matches_definition_and_decreases(tip_graph):
    _, g = tip_graph
    prob = ArapProblem(g.nodes_W, g.edges, g.weights, g.num_free)
    u_c = np.zeros((1, g.num_constrained, 3))
    u_c[0, g.num_fixed:] = [0.0, 0.0, 0.05]
    first = prob.Solve(u_c, 1, 1e-5)
    res = prob.Solve(u_c, 100, 1e-5)
    assert res.energy[0] < 0.5 * first.energy[0]
    assert np.isclose(res.energy[0], brute_energy(g, res.positions_W[0], res.rotations[0]),
                      rtol=1e-8)
    assert np.allclose(res.displacements[0, g.num_free + g.num_fixed:], [0.0, 0.0, 0.05])
    assert np.allclose(res.displacements[0, g.num_free:g.num_free + g.num_fixed], 0.0)


def test_factorizations_agree(tip_graph):
    _, g = tip_graph
    u_c = np.zeros((2, g.num_constrained, 3))
    u_c[:, g.num_fixed:] = [[0.0, 0.03, 0.02]]
    u_c[1, g.num_fixed:] *= -1
    out = [ArapProblem(g.nodes_W, g.edges, g.weights, g.num_free, f).Solve(u_c, 30, 1e-5)
           for f in ("splu", "cholesky", "inverse")]
    for r in out[1:]:
        assert np.allclose(r.energy, out[0].energy, rtol=1e-8)
        assert np.allclose(r.positions_W, out[0].positions_W, atol=1e-9)


def test_energy_grows_with_distance_and_away_costs_more(plant, tip_graph):
    leaf, branch = plant
    p, _ = tip_graph
    d = [0.02, 0.04, 0.06, 0.08]
    away = np.array([1.0, 0.0, 0.0])      # along the leaf, away from the branch
    along = np.array([0.0, 0.0, 1.0])     # parallel to the (vertical) branch
    actions = MakeActions([(p, R_TIP)], [away, along], d)
    preds = PredictDeformations(leaf, branch, actions, CFG, dense=False)
    e = np.array([x.energy for x in preds]).reshape(2, 4)
    assert np.all(np.diff(e, axis=1) > 0)
    assert np.all(e[0] > 3.0 * e[1])
    # The handle reached its target; the leaf near the branch barely moved.
    x = preds[3]
    h = x.node_kind == 2
    assert np.allclose(x.deformed_nodes_W[h] - x.nodes_W[h], 0.08 * away)
    move = np.linalg.norm(x.deformed_nodes_W - x.nodes_W, axis=1)
    near = (x.node_kind == 0) & (x.nodes_W[:, 0] < 0.016)   # petiole, next to the branch
    far = (x.node_kind == 0) & (x.nodes_W[:, 0] > 0.1)      # blade tip
    assert near.any() and far.any()
    assert move[near].max() < 0.25 * 0.08 < 0.75 * 0.08 < move[far].min()


def test_mirrored_leaf_and_pulls_give_equal_energies(plant):
    leaf, branch = plant
    S = np.diag([1.0, -1.0, 1.0])
    # A grasp off the midrib on the +y half, and its mirror image.
    cand = leaf[(leaf[:, 1] > 0.012) & (np.abs(leaf[:, 0] - 0.08) < 0.002)]
    p = cand[np.argmin(cand[:, 1])]
    R = np.column_stack([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    dirs = PullDirections()[[1, 6, 9, 12]]
    a = MakeActions([(p, R)], dirs, [0.04])
    b = MakeActions([(S @ p, S @ R @ S)], dirs @ S, [0.04])
    pa = PredictDeformations(leaf, branch, a, CFG, dense=False)
    pb = PredictDeformations(leaf, branch, b, CFG, dense=False)
    ea, eb = np.array([x.energy for x in pa]), np.array([x.energy for x in pb])
    assert np.ptp(ea) > 0.1 * ea.max()          # the pulls differ from each other
    assert np.allclose(ea, eb, rtol=1e-6)
    d, idx = cKDTree(pb[0].nodes_W).query(pa[0].nodes_W @ S)
    assert d.max() < 1e-9                       # the graphs are mirror images
    assert np.allclose(pa[0].deformed_nodes_W @ S, pb[0].deformed_nodes_W[idx], atol=1e-7)


def test_action_helpers():
    d = PullDirections()
    assert d.shape == (14, 3) and np.allclose(np.linalg.norm(d, axis=1), 1.0)
    assert len(np.unique(np.round(d, 9), axis=0)) == 14
    a = Action([0, 0, 0], np.eye(3), [0.0, 0.03, 0.04])
    assert np.isclose(a.distance, 0.05) and np.allclose(a.direction_W, [0, 0.6, 0.8])
    acts = MakeActions([([0, 0, 0], np.eye(3)), ([1, 0, 0], np.eye(3))], d[:2], [0.02, 0.04])
    assert len(acts) == 8 and acts[5].grasp_id == 1 and acts[5].direction_id == 0


def test_lbfgs_matches_plain_global_local(tip_graph):
    """The accelerated solver (default) minimises the same energy as the
    textbook global-local iterations: run to a tight tolerance both reach
    the same minimum; at the default tolerance the accelerated one is at
    least as low and its energy matches its own positions and rotations."""
    _, g = tip_graph
    prob = ArapProblem(g.nodes_W, g.edges, g.weights, g.num_free)
    u_c = np.zeros((3, g.num_constrained, 3))
    u_c[:, g.num_fixed:] = [[[0.0, 0.0, 0.02]], [[0.04, 0.0, 0.0]], [[0.0, 0.05, -0.03]]]
    tight_plain = prob.Solve(u_c, 5000, 1e-11, method="plain")
    tight_fast = prob.Solve(u_c, 2000, 1e-11)
    assert np.allclose(tight_fast.energy, tight_plain.energy, rtol=1e-6)
    assert np.abs(tight_fast.positions_W - tight_plain.positions_W).max() < 1e-3
    plain = prob.Solve(u_c, 300, 1e-5, method="plain")
    fast = prob.Solve(u_c, 300, 1e-5)
    assert np.all(fast.energy <= plain.energy * (1 + 1e-9))
    assert np.all(fast.iterations <= plain.iterations) and fast.converged.all()
    for a in range(3):
        assert np.isclose(fast.energy[a], brute_energy(g, fast.positions_W[a], fast.rotations[a]),
                          rtol=1e-8)
    with pytest.raises(ValueError):
        prob.Solve(u_c, 10, 1e-5, method="nope")


def test_warm_start_over_distances_reaches_the_same_minimum(tip_graph):
    """Longer pulls along the same direction start from the scaled solution
    of the next shorter one; run tight, this reaches the same energies as
    starting every action from the Laplacian solve."""
    from lmap_drake.deformation.arap import _DistanceChains
    _, g = tip_graph
    prob = ArapProblem(g.nodes_W, g.edges, g.weights, g.num_free)
    dirs = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]])
    dist = [0.04, 0.02, 0.06]
    u_c = np.zeros((6, g.num_constrained, 3))
    u_c[:, g.num_fixed:] = np.array([s * d for d in dirs for s in dist])[:, None]
    pred, ratio, stages = _DistanceChains(u_c)
    assert pred.tolist() == [1, -1, 0, 4, -1, 3]
    assert np.allclose(ratio[[0, 2, 3, 5]], [2.0, 1.5, 2.0, 1.5])
    assert [s.tolist() for s in stages] == [[1, 4], [0, 3], [2, 5]]
    warm = prob.SolveAccelerated(u_c, 2000, 1e-11, warm_start=True)
    cold = prob.SolveAccelerated(u_c, 2000, 1e-11, warm_start=False)
    assert np.allclose(warm.energy, cold.energy, rtol=1e-6)
    assert np.abs(warm.positions_W - cold.positions_W).max() < 1e-3
    quick = prob.SolveAccelerated(u_c, 300, 1e-5, warm_start=True)
    slow = prob.SolveAccelerated(u_c, 300, 1e-5, warm_start=False)
    assert quick.iterations.sum() < slow.iterations.sum()
