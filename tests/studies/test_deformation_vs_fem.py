"""lmap_drake.studies.deformation_vs_fem: the point correspondence and error
measures on a small synthetic tet mesh (the full FEM evaluation,
scripts/eval_deformation_vs_fem.py, is minutes long)."""
import numpy as np

from lmap_drake.studies import deformation_vs_fem as MOD


def _slab(nx=6, ny=4, h=0.01, t=0.002):
    """A thin two-layer box of tets (like the leaf), 5 tets per cube."""
    xs, ys, zs = np.arange(nx + 1) * h, np.arange(ny + 1) * h, np.array([0.0, t / 2, t])
    V = np.array([[x, y, z] for x in xs for y in ys for z in zs])
    idx = lambda i, j, k: (i * (ny + 1) + j) * 3 + k  # noqa: E731
    tets = []
    for i in range(nx):
        for j in range(ny):
            for k in range(2):
                c = [idx(i + a, j + b, k + e) for a in (0, 1) for b in (0, 1) for e in (0, 1)]
                # corners c[abe]: 0=000 1=001 2=010 3=011 4=100 5=101 6=110 7=111
                tets += [[c[0], c[4], c[2], c[1]], [c[4], c[6], c[2], c[7]],
                         [c[4], c[1], c[5], c[7]], [c[2], c[1], c[7], c[3]],
                         [c[4], c[2], c[1], c[7]]]
    return V, np.array(tets)


def test_correspondence_follows_an_affine_map_and_a_bend():
    V, tets = _slab()
    rng = np.random.default_rng(0)
    # Points on the top face and slightly above it (like depth points).
    P = np.c_[rng.uniform(0, 0.06, 200), rng.uniform(0, 0.04, 200),
              0.002 + rng.uniform(-0.0003, 0.0003, 200)]
    t, b, s = MOD.TetCorrespondence(V, tets, P)
    assert np.allclose(MOD.CarryPoints(V, tets, t, b), P)
    assert s.min() > -0.5          # never far outside the chosen tet
    assert (s >= -1e-9).mean() > 0.4
    # An affine map is carried exactly, also for points just outside the mesh.
    A = np.array([[0.9, 0.2, 0.0], [-0.1, 1.1, 0.3], [0.0, 0.1, 1.0]])
    off = np.array([0.01, -0.02, 0.03])
    assert np.allclose(MOD.CarryPoints(V @ A.T + off, tets, t, b), P @ A.T + off)
    # A bend (rotation about y growing with x) moves points with the surface.
    ang = 2.0 * V[:, 0]
    Vb = np.c_[np.sin(ang) * (0.5 - V[:, 2]), V[:, 1], 0.5 - np.cos(ang) * (0.5 - V[:, 2])]
    angP = 2.0 * P[:, 0]
    Pb = np.c_[np.sin(angP) * (0.5 - P[:, 2]), P[:, 1], 0.5 - np.cos(angP) * (0.5 - P[:, 2])]
    assert np.abs(MOD.CarryPoints(Vb, tets, t, b) - Pb).max() < 1e-4


def test_point_errors_and_baselines():
    obs = np.zeros((4, 3))
    dp = np.array([0.04, 0.0, 0.0])
    sim = obs + dp + [0.0, 0.01, 0.0]
    e = MOD.PointErrors(obs + dp, sim, obs, dp)
    assert np.isclose(e["error_cm"], 1.0) and np.isclose(e["baseline_rigid_translation_cm"], 1.0)
    assert np.isclose(e["baseline_no_deformation_cm"], 100 * np.hypot(0.04, 0.01))
    assert np.isclose(MOD.Spearman([1, 2, 3, 4], [10, 20, 30, 25]), 0.8)
    assert MOD.Spearman([1, 1, 1], [1, 2, 3]) is None


def test_correlations_per_scenario_and_pooled():
    rows = lambda k: [{"energy": e * k, "distance_m": d, "strain_percentile_end": 1 + e,  # noqa
                       "strain_percentile_max": 1 + e, "petiole_force_end_N": e,
                       "petiole_force_max_N": e}
                      for e, d in zip([1.0, 2.0, 3.0, 4.0], [0.02, 0.04, 0.06, 0.08])]
    c = MOD.Correlations({"a": rows(1.0), "b": rows(10.0)})
    assert np.isclose(c["per_scenario"]["a"]["strain_percentile_end"], 1.0)
    assert np.isclose(c["pooled_rank_within_scenario"]["petiole_force_max_N"], 1.0)
    assert c["pooled"]["n"] == 8
