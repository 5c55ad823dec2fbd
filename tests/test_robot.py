"""The URDFs in models/ against the UR5's published DH parameters and the
2F-85's published dimensions."""
import numpy as np
from pydrake.math import RigidTransform
from pydrake.multibody.plant import MultibodyPlant

from lmap_drake.robot import (GRIPPER_MAX_WIDTH, UR5_JOINTS, AddUr5AndGripper,
                                      MakeControllerPlant, Ur5DhForwardKinematics)


def _plant():
    plant, ur5, gripper = MakeControllerPlant(RigidTransform())
    return plant, ur5, gripper


def test_urdf_forward_kinematics_equals_dh():
    plant, ur5, _ = _plant()
    context = plant.CreateDefaultContext()
    rng = np.random.default_rng(0)
    flange = plant.GetFrameByName("flange", ur5)
    base = plant.GetFrameByName("base_link", ur5)
    worst_p, worst_R = 0.0, 0.0
    for _ in range(200):
        q = rng.uniform(-np.pi, np.pi, 6)
        plant.SetPositions(context, ur5, q)
        X = plant.CalcRelativeTransform(context, base, flange).GetAsMatrix4()
        T = Ur5DhForwardKinematics(q)
        worst_p = max(worst_p, np.abs(X[:3, 3] - T[:3, 3]).max())
        worst_R = max(worst_R, np.abs(X[:3, :3] - T[:3, :3]).max())
    assert worst_p < 1e-9
    assert worst_R < 1e-9


def test_dh_reference_against_known_pose():
    # All-zero pose: the arm lies along -x of the base, flange at
    # x = a2 + a3, y = -(d4 + d6), z = d1 - d5 (standard UR5 result).
    T = Ur5DhForwardKinematics(np.zeros(6))
    np.testing.assert_allclose(T[:3, 3], [-0.81725, -0.19145, -0.005491], atol=1e-6)


def test_joint_limits_and_velocity_limits():
    plant, ur5, _ = _plant()
    for name in UR5_JOINTS:
        joint = plant.GetJointByName(name, ur5)
        assert joint.velocity_upper_limits()[0] == np.pi
        bound = np.pi if name == "elbow_joint" else 2 * np.pi
        assert joint.position_upper_limits()[0] == bound
        assert joint.position_lower_limits()[0] == -bound


def test_gripper_stroke_pads_and_tcp():
    plant, _, gripper = _plant()
    context = plant.CreateDefaultContext()
    left = plant.GetJointByName("left_finger_joint", gripper)
    right = plant.GetJointByName("right_finger_joint", gripper)
    stroke = left.position_upper_limits()[0] + right.position_upper_limits()[0]
    assert abs(stroke - GRIPPER_MAX_WIDTH) < 1e-12
    # Pad boxes: 22 mm wide (x) and 38 mm long (z) in the gripper frame.
    from pydrake.geometry import SceneGraph
    plant2 = MultibodyPlant(0.0)
    sg = SceneGraph()
    plant2.RegisterAsSourceForSceneGraph(sg)
    _, g2 = AddUr5AndGripper(plant2, RigidTransform())
    plant2.Finalize()
    inspector = sg.model_inspector()
    pads = [g for g in inspector.GetAllGeometryIds() if inspector.GetName(g).endswith("_pad")]
    assert len(pads) == 2
    X_GT = plant.CalcRelativeTransform(context, plant.GetFrameByName("robotiq_base", gripper),
                                       plant.GetFrameByName("tcp", gripper))
    for g in pads:
        size = inspector.GetShape(g)
        assert np.allclose([size.width(), size.height()], [0.022, 0.038])
        # pad centre height (finger frame = gripper frame at zero opening) = TCP height
        assert abs(inspector.GetPoseInFrame(g).translation()[2]
                   - X_GT.translation()[2]) < 1e-12
    # The TCP sits midway between the pads at the pads' centre height.
    left.set_translation(context, 0.02)
    right.set_translation(context, 0.02)
    tcp = plant.GetFrameByName("tcp", gripper)
    lf = plant.GetBodyByName("left_finger", gripper).body_frame()
    rf = plant.GetBodyByName("right_finger", gripper).body_frame()
    p_l = plant.CalcRelativeTransform(context, tcp, lf).translation()
    p_r = plant.CalcRelativeTransform(context, tcp, rf).translation()
    np.testing.assert_allclose(p_l[:2] + p_r[:2], 0.0, atol=1e-12)  # symmetric about TCP
    assert abs(p_l[1] - 0.02) < 1e-12 and abs(p_r[1] + 0.02) < 1e-12
