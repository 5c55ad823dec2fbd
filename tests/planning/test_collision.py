"""The planner's collision pre-filters give the same answers as the full
queries: per-geometry boxes of the robot's samples and per-fruit SDFs."""
import numpy as np
from pydrake.math import RigidTransform, RotationMatrix

from lmap_drake.planning.collision import NearBox, RobotCollisionReason, UnionSdf
from lmap_drake.planning.robot_model import RobotModel
from lmap_drake.station.config import RobotConfig


def _Sphere(center, radius):
    return lambda p: np.linalg.norm(np.asarray(p) - center, axis=1) - radius  # noqa: E731


def test_near_box_per_geometry_keeps_exactly_the_points_in_the_box():
    robot = RobotModel(RobotConfig().X_WB.GetDeterministicValue())
    rng = np.random.default_rng(0)
    q0 = np.array(RobotConfig().initial_q)
    tcp = robot.TcpPose(q0).translation()
    for k in range(6):
        q = q0 + rng.uniform(-0.5, 0.5, 6)
        samples = robot.SurfacePointsByBody(q, 0.01)
        every = robot.SurfacePoints(q, 0.01)
        # boxes around the gripper, across the whole arm, and away from it
        c = tcp + rng.uniform(-0.1, 0.1, 3)
        for lo, hi in ((c - 0.05, c + 0.05), (c - 2.0, c + 2.0), (c + 3.0, c + 3.1)):
            want = every[np.all((every >= lo) & (every <= hi), axis=1)]
            got = NearBox(samples, lo, hi)
            assert got.shape == want.shape
            assert np.array_equal(np.sort(got, axis=0), np.sort(want, axis=0))
        # and the collision reasons agree, hits and misses
        sdf = _Sphere(c, 0.04)
        box = (c - 0.04, c + 0.04)
        for margin in (0.005, 0.05):
            assert RobotCollisionReason(samples, sdf, sdf, margin, box, None) == \
                RobotCollisionReason(every, sdf, sdf, margin, box, None)


def test_union_sdf_is_exact_near_the_fruits_and_a_lower_bound_far_away():
    rng = np.random.default_rng(1)
    centers = [np.array([0.0, 0.0, 0.0]), np.array([0.12, 0.0, 0.05])]
    sdfs = [_Sphere(c, 0.03) for c in centers]
    boxes = [(c - 0.03, c + 0.03) for c in centers]
    union = UnionSdf(sdfs, boxes, pad=0.05)
    p = rng.uniform(-0.12, 0.22, (5000, 3))
    exact = np.min([f(p) for f in sdfs], axis=0)
    got = union(p)
    near = exact < 0.05
    assert near.sum() > 100 and (~near).sum() > 100
    assert np.allclose(got[near], exact[near], atol=1e-12)
    assert np.all(got[~near] <= exact[~near] + 1e-12) and np.all(got[~near] >= 0.05 - 1e-12)
    # a NaN from a fruit's SDF is not hidden by the other fruit
    nan_union = UnionSdf([lambda q: np.full(len(q), np.nan), sdfs[1]], boxes)
    assert np.isnan(nan_union(centers[:1])).all()


def test_the_robot_body_keeps_the_larger_margin_from_a_fruit_the_fingers_the_smaller():
    robot = RobotModel(RobotConfig().X_WB.GetDeterministicValue())
    q = np.array(RobotConfig().initial_q)
    samples = robot.SurfacePointsByBody(q, 0.02)
    assert samples.fingers.any() and not samples.fingers.all()
    body = np.vstack([samples[int(i)] for i in np.flatnonzero(~samples.fingers)])
    finger = np.vstack([samples[int(i)] for i in np.flatnonzero(samples.fingers)])

    def fruit_near(points, gap):
        """A 3 cm sphere whose surface lies ``gap`` from the nearest of
        ``points``, on the side away from the rest of the robot."""
        every = robot.SurfacePoints(q, 0.02)
        p = points[np.argmax(np.linalg.norm(points - every.mean(0), axis=1))]
        out = (p - every.mean(0)) / np.linalg.norm(p - every.mean(0))
        for _ in range(50):     # push out until the nearest robot sample is ``gap`` away
            c = p + (0.03 + gap) * out
            d = np.linalg.norm(every - c, axis=1).min() - 0.03
            p = p + (gap - d) * out
        return _Sphere(c, 0.03), (c - 0.03, c + 0.03)

    sdf, box = fruit_near(body, 0.010)         # 1 cm from the gripper body or arm
    assert RobotCollisionReason(samples, sdf, None, 0.005, box, None) == ""
    assert RobotCollisionReason(samples, sdf, None, 0.005, box, None, 0.015).startswith(
        "robot-body-fruit")
    sdf, box = fruit_near(finger, 0.010)       # 1 cm from a finger only
    assert np.linalg.norm(body - (box[0] + 0.03), axis=1).min() > 0.03 + 0.015
    assert RobotCollisionReason(samples, sdf, None, 0.005, box, None, 0.015) == ""
    assert RobotCollisionReason(samples, sdf, None, 0.012, box, None, 0.015).startswith(
        "robot-fruit")


def test_fruit_set_sdf_keeps_clear_of_every_kept_hypothesis():
    """A point outside the estimate but inside a larger hypothesis (the
    unseen part of the fruit may be there) is inside the set's SDF; without
    hypotheses the set is the estimate."""
    import trimesh
    from lmap_drake.planning.collision import FruitSetSdf, MeshSdf
    from lmap_drake.types import FruitEstimate, ShapeHypotheses
    c = np.array([0.5, 0.0, 0.3])
    small = trimesh.creation.icosphere(3, radius=0.03)
    small.apply_translation(c)
    big = trimesh.creation.icosphere(3, radius=0.045)
    big.apply_translation(c + [0.01, 0, 0])
    est = FruitEstimate(np.asarray(small.vertices), np.asarray(small.faces), np.eye(4),
                        np.zeros(2), c, np.array([0, 0, 1.0]), sdf_W=_Sphere(c, 0.03))
    p = np.array([c + [0.05, 0, 0], c + [0.0, 0, 0.1]])
    sdf, box = FruitSetSdf(est)
    assert sdf is est.sdf_W and np.allclose(box[0], small.vertices.min(0))
    n = 2
    est.hypotheses = ShapeHypotheses(
        vertices_W=[est.vertices_W, np.asarray(big.vertices)], faces=[est.faces, big.faces],
        X_WO=np.tile(np.eye(4), (n, 1, 1)), latents=np.zeros((n, 2)),
        volume_cm3=np.array([113.0, 382.0]), center_W=np.array([c, c]),
        axis_W=np.array([[0, 0, 1.0]] * n), residual_m=np.zeros(n),
        inlier_fraction=np.ones(n), inside_fraction=np.zeros(n), num_fitted=3,
        volume_interval_cm3=np.array([113.0, 382.0]), center_interval_W=np.array([c, c]),
        axis_spread_deg=0.0)
    sdf, (lo, hi) = FruitSetSdf(est)
    d = sdf(p)
    assert est.sdf_W(p[:1])[0] > 0.015 and d[0] < -0.004     # inside the big one only
    assert abs(d[1] - (np.linalg.norm([0.01, 0, 0.1]) - 0.045)) < 0.002
    assert np.allclose(hi, np.asarray(big.vertices).max(0))
    m = MeshSdf(big.vertices, big.faces)(np.array([c + [0.01, 0, 0]]))
    assert abs(m[0] + 0.045) < 0.001


def test_union_sdf_below_a_bound_evaluates_only_near_each_fruit_and_keeps_the_verdict():
    from lmap_drake.planning.collision import BELOW_SLACK, RobotCollisionReason, UnionSdf
    centres = [np.array([0.5, 0.0, 0.3]), np.array([0.7, 0.0, 0.3])]
    calls = []

    def sphere(c):
        def sdf(p):
            calls.append(len(p))
            return np.linalg.norm(p - c, axis=1) - 0.03
        return sdf
    boxes = [(c - 0.03, c + 0.03) for c in centres]
    union = UnionSdf([sphere(c) for c in centres], boxes)
    p = np.random.default_rng(0).uniform([0.4, -0.1, 0.2], [0.8, 0.1, 0.4], (4000, 3))
    full = union(p)
    n_full = sum(calls)
    calls.clear()
    for bound in (0.005, 0.015):
        got = union.Below(p, bound)
        near = full < bound + BELOW_SLACK
        np.testing.assert_array_equal(got[near], full[near])          # exact near the fruits
        assert np.all(got[~near] >= bound)                            # never a false hit
    assert sum(calls) < n_full                                        # fewer evaluations
    # the robot check's verdict and nearest distance are those of the full band
    reasons = []
    for shift in (0.0, 0.012, 0.04):
        pts = np.array([[0.5, -0.03 - shift - 0.001, 0.3], [0.6, -0.2, 0.3]])
        full_union = UnionSdf([sphere(c) for c in centres], boxes)
        reasons.append(RobotCollisionReason(pts, full_union, None, 0.015))
        assert reasons[-1] == RobotCollisionReason(pts, lambda q: full_union(q), None, 0.015)
    assert reasons == ["robot-fruit (1.0 mm)", "robot-fruit (13.0 mm)", ""]


def test_near_cells_keep_every_point_within_the_margin():
    from scipy.spatial import cKDTree
    from lmap_drake.planning.robot_checks import NearCells
    rng = np.random.default_rng(1)
    leaf = rng.uniform(0, 0.3, (3000, 3)) * [1, 1, 0.02]        # a thin sheet
    q = rng.uniform(-0.05, 0.35, (20000, 3))
    for margin in (0.005, 0.012):
        d = cKDTree(leaf).query(q)[0]
        maybe = NearCells(leaf, margin).Maybe(q)
        assert np.all(maybe[d < margin])                          # none lost
        assert maybe.mean() < 0.5                                 # most ruled out
    # margin 0: no grid, nothing ruled out
    assert NearCells(leaf, 0.0).Maybe(q).all()


def _MeshSet(rng):
    import trimesh
    from lmap_drake.planning.collision import MeshSetSdf
    meshes = []
    for c, r in (([0.5, 0.0, 0.3], 0.035), ([0.52, 0.01, 0.31], 0.04)):
        m = trimesh.creation.icosphere(3, radius=r)
        m.apply_translation(c)
        meshes.append((np.asarray(m.vertices), np.asarray(m.faces)))
    return MeshSetSdf(meshes), meshes


def test_mesh_set_lower_below_is_exact_below_the_bound_and_a_bound_above():
    rng = np.random.default_rng(3)
    sdf, _ = _MeshSet(rng)
    p = rng.uniform([0.42, -0.08, 0.22], [0.6, 0.08, 0.4], (5000, 3))
    full = sdf(p)
    for bound in (0.005, 0.015):
        got = sdf.LowerBelow(p, bound)
        near = full < bound
        assert near.any() and (~near).any() and (full < 0).any()
        np.testing.assert_array_equal(got[near], full[near])        # exact (inside too)
        assert np.all(got[~near] >= bound) and np.all(got[~near] <= full[~near] + 1e-6)
        assert np.count_nonzero(got != full) > 0.3 * len(p)          # most were not computed


def test_nearest_below_is_the_smallest_below_distance_exactly_or_at_least_the_bound():
    from lmap_drake.planning.collision import UnionSdf
    rng = np.random.default_rng(4)
    mesh_set, meshes = _MeshSet(rng)
    c = np.array([0.5, 0.0, 0.3])

    def estimate(q):
        return np.linalg.norm(q - c, axis=1) - 0.03
    V = np.vstack([v for v, _ in meshes])
    inner = UnionSdf([estimate, mesh_set], [(c - 0.03, c + 0.03), (V.min(0), V.max(0))], 0.03)
    other_c = np.array([0.62, 0.0, 0.3])
    outer = UnionSdf([inner, lambda q: np.linalg.norm(q - other_c, axis=1) - 0.02],
                     [(V.min(0), V.max(0)), (other_c - 0.02, other_c + 0.02)], 0.03)
    hits = 0
    for sdf in (inner, outer):
        for k in range(40):
            centre = rng.uniform([0.42, -0.08, 0.22], [0.68, 0.08, 0.4])
            pts = centre + rng.normal(0.0, 0.01, (300, 3))
            for bound in (0.005, 0.015):
                ref = float(sdf.Below(pts, bound).min())
                got = sdf.NearestBelow(pts, bound)
                if ref < bound:
                    assert got == ref
                    hits += 1
                else:
                    assert got >= bound
    assert 10 < hits < 150                           # both cases were met
    nan = UnionSdf([lambda q: np.full(len(q), np.nan)], [(c - 0.03, c + 0.03)])
    assert np.isnan(nan.NearestBelow(c[None], 0.005))


def _AssertExactBelow(full, got, bound):
    """``got`` equals the full distances where they are below the per-point
    ``bound`` and is at least the bound elsewhere; both cases occur."""
    below = full < bound
    assert below.any() and (~below).any()
    np.testing.assert_array_equal(got[below], full[below])
    assert np.all(got[~below] >= bound[~below])


def test_mesh_set_lower_below_takes_a_bound_per_point():
    rng = np.random.default_rng(5)
    sdf, _ = _MeshSet(rng)
    p = rng.uniform([0.42, -0.08, 0.22], [0.6, 0.08, 0.4], (3000, 3))
    full = sdf(p)
    bound = rng.uniform(-0.01, 0.02, len(p))
    _AssertExactBelow(full, sdf.LowerBelow(p, bound), bound)


def test_leaf_collision_reason_is_the_same_with_the_mesh_set_bounded():
    """The leaf-fruit check on a fruit set with hypothesis meshes gives the
    same reason (verdict and distance) as on the plain per-point SDF."""
    from lmap_drake.planning.collision import LeafCollisionReason
    rng = np.random.default_rng(6)
    mesh_set, meshes = _MeshSet(rng)
    V = np.vstack([v for v, _ in meshes])
    union = UnionSdf([mesh_set], [(V.min(0), V.max(0))], 0.03)
    rest = np.array([0.5, -0.07, 0.3]) + rng.normal(0, 0.01, (400, 3)) * [1, 0.1, 1]
    reasons = []
    for shift in np.linspace(0.0, 0.04, 9):
        moved = rest + [0.0, shift, 0.0]
        got = LeafCollisionReason(rest, moved, union, 0.005, (V.min(0), V.max(0)))
        reasons.append(got)
        assert got == LeafCollisionReason(rest, moved, lambda q: union(q), 0.005,
                                          (V.min(0), V.max(0)))
    assert "" in reasons and any(r.startswith("leaf-fruit (") for r in reasons)


def test_mesh_set_lower_bound_never_exceeds_the_distance_with_long_and_short_edges():
    import trimesh
    from lmap_drake.planning.collision import MeshSetSdf
    ball = trimesh.creation.icosphere(3, radius=0.03)
    ball.apply_translation([0.5, 0.0, 0.3])
    box = trimesh.creation.box([0.05, 0.04, 0.06])          # 12 long-edged triangles
    box.apply_translation([0.56, 0.0, 0.3])
    sdf = MeshSetSdf([(ball.vertices, ball.faces), (box.vertices, box.faces)])
    p = np.random.default_rng(7).uniform([0.44, -0.06, 0.24], [0.62, 0.06, 0.36], (4000, 3))
    full = sdf(p)
    lb = sdf._LowerBound(p, np.full(len(p), 1.0))
    assert np.all(lb <= np.abs(full) + 1e-6)
    # with short edges only, the bound is within an edge (5 mm) of the distance
    ball_only = MeshSetSdf([(ball.vertices, ball.faces)])
    lb = ball_only._LowerBound(p, np.full(len(p), 1.0))
    full = np.abs(ball_only(p))
    assert np.all(lb <= full + 1e-6) and np.max(full - lb) < 0.006


def test_verdict_only_robot_check_gives_the_same_verdict_without_the_nearest_distance():
    rng = np.random.default_rng(8)
    mesh_set, meshes = _MeshSet(rng)
    c = np.array([0.5, 0.0, 0.3])
    V = np.vstack([v for v, _ in meshes])
    calls = []

    def estimate(q):
        calls.append(len(q))
        return np.linalg.norm(q - c, axis=1) - 0.03
    fruit = UnionSdf([estimate, mesh_set], [(c - 0.03, c + 0.03), (V.min(0), V.max(0))], 0.03)
    box = (V.min(0), V.max(0))
    verdicts = []
    for k in range(60):
        pts = rng.uniform([0.42, -0.08, 0.22], [0.6, 0.08, 0.4]) + rng.normal(0, 0.005, (200, 3))
        full = RobotCollisionReason(pts, fruit, None, 0.005, box)
        n = len(calls)
        fast = RobotCollisionReason(pts, fruit, None, 0.005, box, verdict_only=True)
        assert full.split(" (")[0] == fast.split(" (")[0]
        assert fast in ("", "robot-fruit (verdict only)")
        verdicts.append(fast)
        if fast and len(calls) == n:
            verdicts.append("decoder skipped")
    assert "" in verdicts and "decoder skipped" in verdicts


def test_union_lower_below_is_exact_below_the_bound_with_an_estimate_and_meshes():
    rng = np.random.default_rng(9)
    mesh_set, meshes = _MeshSet(rng)
    c = np.array([0.5, 0.0, 0.3])
    V = np.vstack([v for v, _ in meshes])
    fruit = UnionSdf([_Sphere(c, 0.037), mesh_set], [(c - 0.037, c + 0.037),
                                                     (V.min(0), V.max(0))], 0.03)
    p = rng.uniform([0.42, -0.08, 0.22], [0.6, 0.08, 0.4], (4000, 3))
    full = fruit(p)
    bound = rng.uniform(-0.01, 0.015, len(p))
    _AssertExactBelow(full, fruit.LowerBelow(p, bound), bound)


def test_occupancy_rays_point_along_every_positive_axis():
    """``MeshSetSdf._Inside`` asks Open3D only about points not beyond a
    mesh's box: its occupancy rays must run toward +x, +y and +z (an open
    plane counts once from below along each axis, never from above)."""
    import open3d as o3d
    for axis in range(3):
        a, b = [i for i in range(3) if i != axis]
        V = np.zeros((4, 3), np.float32)
        V[:, a], V[:, b] = [-5, 5, 5, -5], [-5, -5, 5, 5]
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(V), o3d.core.Tensor(np.array([[0, 1, 2], [0, 2, 3]],
                                                                         np.uint32)))
        p = np.zeros((2, 3), np.float32)
        p[:, axis] = [-1.0, 1.0]
        np.testing.assert_array_equal(scene.compute_occupancy(o3d.core.Tensor(p)).numpy(),
                                      [1.0, 0.0])


def test_mesh_set_inside_is_open3d_occupancy_of_every_mesh():
    import open3d as o3d
    rng = np.random.default_rng(10)
    sdf, meshes = _MeshSet(rng)
    p = rng.uniform([0.42, -0.08, 0.22], [0.6, 0.08, 0.4], (5000, 3)).astype(np.float32)
    q = o3d.core.Tensor(p)
    ref = np.zeros(len(p), bool)
    for one in sdf._each:
        ref |= one.compute_occupancy(q).numpy() > 0.5
    assert ref.any() and (~ref).any()
    np.testing.assert_array_equal(sdf._Inside(q), ref)


def test_distance_anchors_give_the_same_leaf_fruit_reason_with_fewer_exact_distances():
    """Anchored at the rest leaf, the mesh set computes fewer exact
    distances and the leaf-fruit check gives the same reasons (verdict and
    distance) as without anchors."""
    from lmap_drake.planning.collision import DistanceAnchors, LeafCollisionReason, MeshSetSdf
    rng = np.random.default_rng(11)
    mesh_set, meshes = _MeshSet(rng)
    V = np.vstack([v for v, _ in meshes])
    c = np.array([0.5, 0.0, 0.3])
    union = UnionSdf([_Sphere(c, 0.037), mesh_set], [(c - 0.037, c + 0.037),
                                                     (V.min(0), V.max(0))], 0.03)
    box = (V.min(0), V.max(0))
    rest = np.array([0.5, -0.06, 0.3]) + rng.normal(0, 0.012, (600, 3)) * [1, 0.1, 1]
    anchors = DistanceAnchors(union, rest)
    assert list(anchors.bounds) == [id(mesh_set)]
    rest_d = union(rest)
    counted = {"plain": 0, "anchored": 0}
    exact = MeshSetSdf.LowerBelow

    def counting(key):
        def low(self, p, bound, anchors=None):
            out = exact(self, p, bound, anchors)
            counted[key] += int(np.count_nonzero(out == self(p)))
            return out
        return low
    reasons = []
    for shift in np.linspace(0.0, 0.04, 9):
        moved = rest + [0.0, shift, 0.0] + rng.normal(0, 0.002, rest.shape)
        MeshSetSdf.LowerBelow = counting("plain")
        try:
            plain = LeafCollisionReason(rest, moved, union, 0.005, box, rest_d)
            MeshSetSdf.LowerBelow = counting("anchored")
            got = LeafCollisionReason(rest, moved, union, 0.005, box, rest_d, anchors=anchors)
        finally:
            MeshSetSdf.LowerBelow = exact
        assert got == plain
        reasons.append(got)
    assert "" in reasons and any(r.startswith("leaf-fruit (") for r in reasons)
    assert counted["anchored"] < counted["plain"]
    # the anchor bound never exceeds the distance
    moved = rest + rng.normal(0, 0.01, rest.shape)
    assert np.all(anchors.Bound(mesh_set, moved) <= np.abs(mesh_set(moved)) + 1e-7)


def test_mesh_set_first_hit_has_the_verdict_of_the_nearest_distance():
    rng = np.random.default_rng(12)
    sdf, _ = _MeshSet(rng)
    verdicts = set()
    for k in range(80):
        pts = rng.uniform([0.42, -0.08, 0.22], [0.6, 0.08, 0.4]) + rng.normal(0, 0.004, (150, 3))
        for bound in (0.005, 0.015):
            full = sdf.NearestWithin(pts, bound)
            fast = sdf.NearestWithin(pts, bound, first_hit=True)
            assert (fast < bound) == (full < bound)
            if fast >= bound:
                assert fast == full == bound
            verdicts.add((full < bound, bool(np.any(sdf(pts) < 0))))
    assert {(True, True), (True, False), (False, False)} <= verdicts   # inside, near, clear
