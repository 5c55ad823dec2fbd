"""The compiled L-BFGS ARAP solver (arap_kernels) against the plain
global-local solver and against itself (lane scheduling, threads)."""
import numpy as np
import pytest

from lmap_drake.deformation import (
    ArapProblem, MakeActions, PredictDeformations,
    PullDirections)
from lmap_drake.deformation import arap_kernels as K
from lmap_drake.deformation.rotations import PolarRotationSvd

from leaf_fixtures import R_TIP, TEST_CONFIG as CFG


@pytest.fixture(scope="module")
def problem(tip_graph):
    _, g = tip_graph
    # 5 directions x 3 distances: 15 actions (more than the lanes) in chains.
    dirs = PullDirections()[::3]
    u_c = np.zeros((15, g.num_constrained, 3))
    u_c[:, g.num_fixed:] = np.array([s * d for d in dirs for s in (0.02, 0.04, 0.06)])[:, None]
    return ArapProblem(g.nodes_W, g.edges, g.weights, g.num_free), u_c


def test_polar_kernel_matches_svd_including_the_fallback():
    rng = np.random.default_rng(5)
    M = rng.normal(size=(203, 3, 3))            # not a multiple of the lanes
    for maxit in (4, 0):                        # 0: every entry through the SVD fallback
        q = np.zeros((203, 4))
        q[:, 0] = 1.0
        R = K.PolarRotations(M, q, K.LANES, maxit, 1e-8, 1e-6, 1e-5)
        assert np.abs(R - PolarRotationSvd(M)).max() < 1e-6
        assert np.allclose(np.linalg.det(R), 1.0)
        assert np.allclose(np.linalg.norm(q, axis=1), 1.0)


def test_compiled_lbfgs_close_to_the_minimum_like_plain(problem):
    """At the default tolerance (1e-5 relative energy decrease per
    iteration) the compiled L-BFGS energies are within 2e-4 (relative) of
    the tight minimum (measured 9e-5; the plain solver at the same
    tolerance: 5e-4) and the positions within 2 mm (both ~1 mm)."""
    prob, u_c = problem
    tight = prob.Solve(u_c, 5000, 1e-11, method="plain")
    fast = prob.Solve(u_c, 300, 1e-5)
    plain = prob.Solve(u_c, 300, 1e-5, method="plain")
    rel = np.abs(fast.energy - tight.energy) / tight.energy
    assert rel.max() < 2e-4
    assert np.abs(fast.positions_W - tight.positions_W).max() < 2e-3
    assert rel.max() <= (np.abs(plain.energy - tight.energy) / tight.energy).max()
    assert fast.converged.all() and fast.iterations.sum() < 0.5 * plain.iterations.sum()


def test_lane_scheduling_does_not_change_results(problem):
    """Each action's iterates are independent of the lane it runs in and
    of the other actions: solving every warm-start chain on its own gives
    the batch results (to round-off)."""
    prob, u_c = problem
    batch = prob.Solve(u_c, 300, 1e-5)
    for k in range(0, 15, 3):
        solo = prob.Solve(u_c[k:k + 3], 300, 1e-5)
        assert np.allclose(solo.energy, batch.energy[k:k + 3], rtol=1e-9, atol=0)
        assert np.abs(solo.positions_W - batch.positions_W[k:k + 3]).max() < 1e-12
        assert (solo.iterations == batch.iterations[k:k + 3]).all()


def test_threads_over_grasps_give_the_same_predictions(plant):
    leaf, branch = plant
    tip = leaf[np.argmax(leaf[:, 0] - 5 * np.abs(leaf[:, 1]))] - [0.01, 0, 0]
    mid = tip - [0.03, 0.0, 0.0]
    actions = MakeActions([(tip, R_TIP), (mid, R_TIP)], PullDirections()[:3], [0.02, 0.04])
    one = PredictDeformations(leaf, branch, actions, CFG, dense=False, workers=1)
    two = PredictDeformations(leaf, branch, actions, CFG, dense=False, workers=2)
    assert [a.action for a in one] == actions
    for a, b in zip(one, two):
        assert a.action == b.action and a.energy == b.energy
        assert np.array_equal(a.deformed_nodes_W, b.deformed_nodes_W)


def test_factorizations_agree_for_the_plain_solver(problem):
    """``factorization`` now only selects the plain solver's L_ff solve (the
    compiled solver always uses the sparse LU): all three agree there."""
    prob, u_c = problem
    g = (prob.rest_W, prob.edges, prob.weights, prob.num_free)
    out = [ArapProblem(*g, factorization=f).Solve(u_c[:4], 40, 1e-5, method="plain")
           for f in ("splu", "cholesky", "inverse")]
    for r in out[1:]:
        assert np.allclose(r.energy, out[0].energy, rtol=1e-8)
        assert np.allclose(r.positions_W, out[0].positions_W, atol=1e-9)
    with pytest.raises(ValueError):
        ArapProblem(*g, factorization="nope")
