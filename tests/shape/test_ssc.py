import dataclasses as dc

import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial.transform import Rotation

from lmap_drake.shape.config import ReestimateConfig, ShapeConfig, SscConfig
from lmap_drake.shape.baselines import FitHoma, FitSuperellipsoid
from lmap_drake.shape.deepsdf import DecoderSdf, LoadDecoder
from lmap_drake.shape.free_space import FreeSpacePoints
from lmap_drake.shape.metrics import CenterErrorCm, MeshCentroid, MeshChamferCm
from lmap_drake.shape.ssc import Adam, MakeFruitEstimate, OptimizeShape

CAM = np.array([0.5, -0.6, 0.47])


@pytest.fixture(scope="module")
def template():
    torch.set_num_threads(1)
    dec, mean, extra = LoadDecoder(ShapeConfig().weights_file)
    return dec, mean, extra["train_latents"].numpy()


def _gt(dec, z, angle_deg=12.0, t=(0.5, -0.03, 0.33), s=1.0):
    R = Rotation.from_rotvec(np.radians(angle_deg) * np.array([1.0, 0.3, 0]) /
                             np.linalg.norm([1.0, 0.3, 0])).as_matrix()
    return MakeFruitEstimate(dec, z, s, R, np.array(t), 0.003), R


def _visible_points(est, keep_right_half=False, n=1500, seed=0):
    m = trimesh.Trimesh(est.vertices_W, est.faces, process=False)
    pts, fi = trimesh.sample.sample_surface(m, 20000, seed=seed)
    facing = np.einsum("ij,ij->i", m.face_normals[fi], CAM - pts) > 0.2 * np.linalg.norm(
        CAM - pts, axis=1)
    if keep_right_half:  # a leaf hides the left half
        facing &= pts[:, 0] > MeshCentroid(est.vertices_W, est.faces)[0] - 0.005
    pts = pts[facing]
    return pts[np.random.default_rng(seed).choice(len(pts), min(n, len(pts)), replace=False)]


def test_ssc_recovers_pose_and_shape_better_than_init(template):
    dec, mean, lat = template
    gt, R = _gt(dec, lat[3])
    obs = _visible_points(gt, keep_right_half=True)
    P = SscConfig(iterations=150)
    est = OptimizeShape(dec, mean, obs, CAM, [], None, P)
    c = obs.mean(0)
    t0 = c + 0.01 * (c - CAM) / np.linalg.norm(c - CAM)
    init = MakeFruitEstimate(dec, mean, 1.0, np.eye(3), t0, 0.003)
    cd_est = MeshChamferCm(est.vertices_W, est.faces, gt.vertices_W, gt.faces, 8000)
    cd_init = MeshChamferCm(init.vertices_W, init.faces, gt.vertices_W, gt.faces, 8000)
    ce_est = CenterErrorCm(est.center_W, gt.center_W)
    ce_init = CenterErrorCm(init.center_W, gt.center_W)
    assert cd_est < 0.7 * cd_init, (cd_est, cd_init)
    assert ce_est < ce_init and ce_est < 0.6, (ce_est, ce_init)
    # Loss went down; the trace has one record per iteration (+ timing).
    tr = [r for r in est.loss_trace if r["it"] >= 0]
    assert len(tr) == 150 and tr[-1]["total"] < tr[0]["total"]
    # X_WO maps the canonical frame to W: the object origin is t, the
    # peduncle axis is its z column, and sdf_W is negative at the centre.
    np.testing.assert_allclose(est.X_WO[:3, 2] / np.linalg.norm(est.X_WO[:3, 2]),
                               est.peduncle_axis_W, atol=1e-9)
    assert est.sdf_W(est.X_WO[:3, 3][None])[0] < -0.01


def test_negative_loss_pushes_surface_out_of_free_space(template):
    dec, mean, lat = template
    gt, R = _gt(dec, lat[5], angle_deg=0.0)
    obs = _visible_points(gt, n=800)
    free = FreeSpacePoints(CAM, obs, obs, 0.003)
    assert len(free) > 300
    P = SscConfig(iterations=80)
    init = dict(s=1.35)
    with_neg = OptimizeShape(dec, mean, obs, CAM, [(free, 1.0)], None, P, init=init)
    without = OptimizeShape(dec, mean, obs, CAM, [], None, dc.replace(P, w_neg=0.0), init=init)
    start = MakeFruitEstimate(dec, mean, 1.35, np.eye(3),
                              obs.mean(0) + 0.01 * (obs.mean(0) - CAM) /
                              np.linalg.norm(obs.mean(0) - CAM), 0.004)

    def inside(est):
        return float(np.mean(est.sdf_W(free) < -0.001))

    assert inside(start) > 0.02
    assert inside(with_neg) < 0.5 * inside(without) + 1e-9
    assert inside(with_neg) < 0.01


def test_baselines_run_and_supeps_fits_an_ellipsoid():
    m = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    m.apply_scale([0.035, 0.035, 0.045])
    m.apply_translation([0.5, -0.03, 0.33])
    pts, _ = trimesh.sample.sample_surface(m, 3000, seed=1)
    est = FitSuperellipsoid(pts, CAM)
    assert MeshChamferCm(est.vertices_W, est.faces, m.vertices, m.faces, 5000) < 0.15
    assert abs(abs(est.peduncle_axis_W[2]) - 1) < 0.05
    assert np.all(est.sdf_W(m.vertices * 0 + [0.5, -0.03, 0.33])[:1] < 0)


def test_homa_ignores_scene_terms(template):
    dec, mean, lat = template
    gt, _ = _gt(dec, lat[1])
    obs = _visible_points(gt, n=600)
    est = FitHoma(dec, mean, obs, CAM, SscConfig(iterations=30))
    tr = [r for r in est.loss_trace if r["it"] >= 0]
    assert all(r["neg"] == 0 and r["ped"] == 0 for r in tr)


def test_params_from_config_reestimate():
    cfg = ShapeConfig().ssc
    p = cfg
    q = ReestimateConfig(cfg)
    assert (p.w_sur, p.w_neg, p.w_ped, p.w_reg) == (1.0, 2.0, 0.1, 1.0)
    assert p.w_neg_completed_branch == 0.1
    assert q.w_ped == cfg.reestimate_w_ped == 0.01
    assert q.w_neg_completed_branch == 0.01
    # the first estimate slows the rotation; the re-estimate after the
    # action keeps plain Adam
    assert (p.rotation_lr_scale, q.rotation_lr_scale) == (0.3, 1.0)
    # both hold the rotation still at first, from their own keys
    assert (p.rotation_hold_steps, q.rotation_hold_steps) == (50, 50)
    assert (p.w_rot, q.w_rot) == (0.0, 0.0)
    cfg.rotation_hold_steps, cfg.reestimate_rotation_hold_steps = 7, 3
    cfg.w_rot, cfg.reestimate_w_rot = 0.5, 0.2
    p, q = cfg, ReestimateConfig(cfg)
    assert (p.rotation_hold_steps, q.rotation_hold_steps, p.w_rot, q.w_rot) == (7, 3, 0.5, 0.2)


def test_the_rotation_is_held_still_for_the_first_steps_then_turns(template):
    """``rotation_hold_steps``: R stays exactly the start for those steps
    while z, s and t move, then turns toward the tilted truth; HoMa-style
    has no hold (its fruit turns from the first step)."""
    dec, mean, lat = template
    gt, R = _gt(dec, lat[2], angle_deg=15.0)
    obs = _visible_points(gt, n=800)
    est = OptimizeShape(dec, mean, obs, CAM, [], None,
                        SscConfig(iterations=60, rotation_hold_steps=20, w_ped=0.0))
    tr = [r for r in est.loss_trace if r["it"] >= 0]
    axes = np.array([r["axis"] for r in tr])
    assert np.allclose(axes[:21], [0, 0, 1], atol=1e-6)      # pose of steps 0-20 (R before each step)
    assert abs(tr[20]["s"] - tr[0]["s"]) > 1e-4              # ... while the scale moved
    tilt = lambda a: np.degrees(np.arccos(np.clip(a @ R[:, 2], -1, 1)))   # noqa: E731
    assert tilt(axes[-1]) < tilt(axes[0]) - 0.5                # then it turned toward the truth
    homa = FitHoma(dec, mean, obs, CAM, SscConfig(iterations=5, rotation_hold_steps=20))
    assert not np.allclose(homa.loss_trace[4]["axis"], [0, 0, 1], atol=1e-6)


def test_adam_moves_a_weakly_observed_parameter_at_full_speed_unless_scaled():
    """Why ``rotation_lr_scale``: Adam's step is about lr whatever the
    gradient's size, so a parameter with a 1e6x weaker but steady gradient
    drifts as fast as a well-observed one; its scale bounds that drift."""
    moved = {}
    for scale in (1.0, 0.3):
        a, b = torch.zeros(1, requires_grad=True), torch.zeros(1, requires_grad=True)
        opt = Adam([a, b], lr=0.01, scales=[1.0, scale])
        for _ in range(50):
            loss = 100 * (a - 1) ** 2 + 1e-4 * (b - 1) ** 2
            opt.zero_grad()
            loss.sum().backward()
            opt.step()
        moved[scale] = float(b.detach())
    assert moved[1.0] > 0.45                      # ~50 full steps of 0.01
    assert 0.13 < moved[0.3] <= 0.3 * 50 * 0.01 * 1.001


def _arc_stalk(top, axis, length=0.06, angle_deg=50.0, radius=0.004, n=1500, seed=0):
    """Surface samples (W) of a curved stalk leaving ``top`` along ``axis``
    and bending ``angle_deg`` sideways over ``length`` (a visible peduncle)."""
    from lmap_drake.plants.pepper import MakePeduncle
    tube = MakePeduncle(np.zeros(3), np.radians(angle_deg), 0.7, length, radius)
    R = Rotation.align_vectors([axis], [[0, 0, 1.0]])[0].as_matrix()
    pts, _ = trimesh.sample.sample_surface(tube, n, seed=seed)
    return pts @ R.T + top


def test_visible_curved_peduncle_does_not_inflate_the_fruit(template):
    """A long curved stalk in view above the fruit, its base hidden (as
    behind a leaf): the peduncle term (only across the axis, Huber, no pull
    on the scale) aligns the axis but does not drag the fruit's top up to
    the lowest visible piece of the stalk (the paper's term on all of T_WO
    stretched such fruits toward it)."""
    dec, mean, lat = template
    s_true = 0.85
    gt, R = _gt(dec, lat[5], s=s_true)
    obs = _visible_points(gt, keep_right_half=True)
    axis = R[:, 2]
    top_O = np.array([[0.0, 0.0, 0.0]])
    from lmap_drake.shape.ssc import PeduncleTemplatePoints
    top_O = PeduncleTemplatePoints(dec, torch.as_tensor(lat[5]), 10).mean(0)
    top_W = s_true * R @ top_O + gt.X_WO[:3, 3]
    stalk = _arc_stalk(top_W - 0.004 * axis, axis)
    stalk = stalk[np.linalg.norm(stalk - top_W, axis=1) > 0.015]    # its base is hidden
    # Without the base gate (``peduncle_base_distance`` 0), so the visible
    # upper stalk does reach the term.
    est = OptimizeShape(dec, mean, obs, CAM, [(stalk, 1.0)], stalk,
                        SscConfig(peduncle_base_distance=0.0))
    tr = [r for r in est.loss_trace if r["it"] >= 0]
    assert sum(r["ped"] > 0 for r in tr) > 100        # the peduncle term was active
    s_est = float(np.cbrt(abs(np.linalg.det(est.X_WO[:3, :3]))))
    vol = lambda e: abs(trimesh.Trimesh(e.vertices_W, e.faces).volume)   # noqa: E731
    assert abs(vol(est) / vol(gt) - 1) < 0.3, (vol(est) * 1e6, vol(gt) * 1e6, s_est)
    ang = np.degrees(np.arccos(np.clip(est.peduncle_axis_W @ axis, -1, 1)))
    assert ang < 12.0, ang


def test_initial_pose_from_observation(template):
    """With init_from_observation: scale 1 unless the observed spread needs
    a larger fruit, within init_scale_bounds; centre behind the points by
    the template's size. Without (the default): the old start."""
    from lmap_drake.shape.ssc import InitialPose, TemplateStats
    dec, mean, _ = template
    st = TemplateStats(dec, mean)
    assert 0.02 < st["radius"] < st["extent"] < 0.12
    rng = np.random.default_rng(0)
    c = np.array([0.5, -0.03, 0.33])
    away = (c - CAM) / np.linalg.norm(c - CAM)
    small = c + rng.normal(scale=0.004, size=(200, 3))
    on = SscConfig(init_from_observation=True)
    s0, t0 = InitialPose(dec, mean, small, CAM, on)
    assert s0 == 1.0
    np.testing.assert_allclose((t0 - small.mean(0)) @ away, 0.8 * st["radius"], rtol=1e-6)
    wide = small.copy()
    wide[:, 0] += np.linspace(-1, 1, 200) * 0.75 * st["extent"]      # spread 1.5 x extent
    s1, _ = InitialPose(dec, mean, wide, CAM, on)
    assert 1.45 < s1 < 1.75        # spread 1.5 x extent plus the noise
    s2, _ = InitialPose(dec, mean, wide, CAM, dc.replace(on, init_scale_bounds=[0.5, 1.2]))
    assert s2 == 1.2
    s3, t3 = InitialPose(dec, mean, wide, CAM, SscConfig())
    small = wide
    assert s3 == 1.0
    np.testing.assert_allclose(t3, small.mean(0) + 0.01 * (small.mean(0) - CAM) /
                               np.linalg.norm(small.mean(0) - CAM))


def test_the_variety_volume_sets_the_start_and_the_fitted_size(template):
    """shape.fruit_volume_cm3: the start scale gives the template that
    volume (0 keeps scale 1); with a quarter of a small fruit in view the
    fitted size follows the start, so a small variety's prior ends nearer
    the truth than the template's own size."""
    from lmap_drake.shape.metrics import MeshVolume
    from lmap_drake.shape.ssc import InitialPose, PriorScale, TemplateStats
    dec, mean, lat = template
    v_template = TemplateStats(dec, mean)["volume"] * 1e6
    assert PriorScale(dec, mean, 0.0) == 1.0
    assert PriorScale(dec, mean, v_template / 8) == pytest.approx(0.5)
    pts = np.array([0.5, -0.03, 0.33]) + np.random.default_rng(0).normal(scale=0.004, size=(50, 3))
    s0, _ = InitialPose(dec, mean, pts, CAM, SscConfig(fruit_volume_cm3=60.0))
    assert s0 ** 3 * v_template == pytest.approx(60.0, rel=1e-6)
    gt, _ = _gt(dec, lat[3], s=0.7)                 # a small pepper
    v_true = abs(MeshVolume(gt.vertices_W, gt.faces)) * 1e6
    obs = _visible_points(gt, n=400)
    obs = obs[obs[:, 2] < np.quantile(obs[:, 2], 0.3)]     # its lower part only
    P = SscConfig(iterations=150)
    fits = {v: OptimizeShape(dec, mean, obs, CAM, [], None,
                             dc.replace(P, fruit_volume_cm3=v)) for v in (0.0, v_true)}
    err = {v: abs(abs(MeshVolume(f.vertices_W, f.faces)) * 1e6 - v_true) for v, f in fits.items()}
    assert err[v_true] < 0.5 * err[0.0], (err, v_true)


def _stalk_case(dec, lat, hide_base: bool):
    """A fruit (12 deg tilt) with its right half in view and a curved stalk
    (50 deg bend over 6 cm) leaving its top; ``hide_base``: the stalk's
    first 1.5 cm is hidden (as behind a leaf)."""
    gt, R = _gt(dec, lat[5], s=0.85)
    obs = _visible_points(gt, keep_right_half=True)
    axis = R[:, 2]
    from lmap_drake.shape.ssc import PeduncleTemplatePoints
    top_O = PeduncleTemplatePoints(dec, torch.as_tensor(lat[5]), 10).mean(0)
    top_W = 0.85 * R @ top_O + gt.X_WO[:3, 3]
    stalk = _arc_stalk(top_W - 0.004 * axis, axis)
    if hide_base:
        stalk = stalk[np.linalg.norm(stalk - top_W, axis=1) > 0.015]
    return gt, axis, obs, stalk


def test_peduncle_base_gate_uses_only_the_stalk_where_it_meets_the_fruit(template):
    """``peduncle_base_distance``: only branch samples on the current fruit
    surface pull the template's top. A stalk seen from its base keeps the
    term active; a stalk whose base is hidden leaves it (almost) idle, so
    the curved, visible part cannot tilt the fruit."""
    dec, mean, lat = template
    P = SscConfig(peduncle_base_distance=0.01)
    ped = {}
    for hide in (False, True):
        gt, axis, obs, stalk = _stalk_case(dec, lat, hide)
        est = OptimizeShape(dec, mean, obs, CAM, [(stalk, 1.0)], stalk, P)
        tr = [r for r in est.loss_trace if r["it"] >= 0]
        ped[hide] = sum(r["ped"] > 0 for r in tr)
        ang = np.degrees(np.arccos(np.clip(est.peduncle_axis_W @ axis, -1, 1)))
        assert ang < 12.0, (hide, ang)
    assert ped[False] > 150, ped
    assert ped[True] < ped[False] / 2, ped


def test_rotation_prior_keeps_the_axis_near_the_start(template):
    """``w_rot`` pulls R toward its start (upright: peppers hang). Half of
    a fruit tilted 12 deg in view: without the prior the fit turns toward
    the tilt; with a strong prior it stays near upright."""
    dec, mean, lat = template
    gt, axis, obs, stalk = _stalk_case(dec, lat, True)
    turn = {}
    for w_rot in (0.0, 3.0):
        est = OptimizeShape(dec, mean, obs, CAM, [(stalk, 1.0)], None,
                            SscConfig(w_rot=w_rot, w_ped=0.0))
        turn[w_rot] = np.degrees(np.arccos(np.clip(est.peduncle_axis_W[2], -1, 1)))
    assert turn[3.0] < turn[0.0], turn
    assert turn[3.0] < 8.0, turn


def test_only_the_negatives_inside_carry_a_gradient(template):
    """The fit sends only the active negatives inside the surface through
    the backward pass: over a pose and latent off the template, the
    negative term of all of them and of those inside alone give the same
    gradient in the latent and the points (no coupling across rows)."""
    dec, mean, lat = template
    g = torch.Generator().manual_seed(3)
    z0 = torch.as_tensor(lat[1], dtype=torch.float32)
    x0 = (torch.rand(300, 3, generator=g) - 0.5) * 0.12
    with torch.no_grad():
        inside = DecoderSdf(dec, z0, x0) < 0
    assert 10 < int(inside.sum()) < 290          # both kinds among them
    grads = []
    for rows in (torch.ones(300, dtype=torch.bool), inside):
        z = z0.clone().requires_grad_(True)
        x = x0.clone().requires_grad_(True)
        torch.relu(-DecoderSdf(dec, z, x[rows])).sum().backward()
        grads.append((z.grad, x.grad))
    torch.testing.assert_close(grads[1][0], grads[0][0], rtol=1e-5, atol=1e-7)
    torch.testing.assert_close(grads[1][1], grads[0][1], rtol=1e-5, atol=1e-7)
    assert float(grads[0][1][~inside].abs().max()) == 0.0
