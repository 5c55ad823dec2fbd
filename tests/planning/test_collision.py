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
