"""UR5 + Robotiq 2F-85 models: loading into a MultibodyPlant, the DH forward
kinematics they are built from, and the controller plant used for gravity
compensation and IK."""
from __future__ import annotations

import numpy as np
from pydrake.math import RigidTransform
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import ModelInstanceIndex

from lmap_drake.paths import MODELS_PACKAGE, PACKAGE_XML

UR5_URL = f"package://{MODELS_PACKAGE}/ur5/ur5.urdf"
ROBOTIQ_URL = f"package://{MODELS_PACKAGE}/robotiq_2f85/robotiq_2f85.urdf"

# UR5 DH parameters (m, rad), DESIGN.md section 4.
UR5_DH_D = np.array([0.089159, 0.0, 0.0, 0.10915, 0.09465, 0.0823])
UR5_DH_A = np.array([0.0, -0.425, -0.39225, 0.0, 0.0, 0.0])
UR5_DH_ALPHA = np.array([np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0])
UR5_VELOCITY_LIMIT = np.pi  # rad/s
GRIPPER_MAX_WIDTH = 0.085  # m
UR5_JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
              "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]
GRIPPER_JOINTS = ["left_finger_joint", "right_finger_joint"]


def Ur5DhForwardKinematics(q: np.ndarray) -> np.ndarray:
    """4x4 pose of the flange (DH frame 6) in the base frame, standard DH."""
    return Ur5DhFrames(q)[-1]


def Ur5DhFrames(q: np.ndarray) -> list[np.ndarray]:
    """4x4 poses of DH frames 0 (base) .. 6 (flange) in the base frame:
    frame 1 sits on the shoulder, 2 at the elbow, 3-5 at the wrists."""
    T = np.eye(4)
    frames = [T]
    for i in range(6):
        ct, st = np.cos(q[i]), np.sin(q[i])
        ca, sa = np.cos(UR5_DH_ALPHA[i]), np.sin(UR5_DH_ALPHA[i])
        A = np.array([[ct, -st * ca, st * sa, UR5_DH_A[i] * ct],
                      [st, ct * ca, -ct * sa, UR5_DH_A[i] * st],
                      [0.0, sa, ca, UR5_DH_D[i]],
                      [0.0, 0.0, 0.0, 1.0]])
        T = T @ A
        frames.append(T)
    return frames


def MakeParser(plant: MultibodyPlant) -> Parser:
    """A Parser whose package map resolves ``package://lmap_drake_models``."""
    parser = Parser(plant)
    if not parser.package_map().Contains(MODELS_PACKAGE):
        parser.package_map().AddPackageXml(str(PACKAGE_XML))
    return parser


def AddUr5AndGripper(plant: MultibodyPlant, X_WB: RigidTransform,
                     parser: Parser | None = None,
                     ) -> tuple[ModelInstanceIndex, ModelInstanceIndex]:
    """Adds the UR5 (base welded at ``X_WB``) and the 2F-85 welded to its
    flange. Returns (ur5, gripper) model instances. Frames: ``base_link``,
    ``flange``, ``robotiq_base``, ``tcp`` (between the pads, z = approach,
    fingers close along y)."""
    parser = parser or MakeParser(plant)
    ur5 = parser.AddModels(url=UR5_URL)[0]
    gripper = parser.AddModels(url=ROBOTIQ_URL)[0]
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("base_link", ur5), X_WB)
    plant.WeldFrames(plant.GetFrameByName("flange", ur5),
                     plant.GetFrameByName("robotiq_base", gripper), RigidTransform())
    return ur5, gripper


def MakeControllerPlant(X_WB: RigidTransform, time_step: float = 0.0
                        ) -> tuple[MultibodyPlant, ModelInstanceIndex, ModelInstanceIndex]:
    """A finalized plant holding only the UR5 and gripper (8 positions:
    6 arm joints then the two half-openings), for gravity compensation,
    forward kinematics and IK."""
    plant = MultibodyPlant(time_step)
    ur5, gripper = AddUr5AndGripper(plant, X_WB)
    plant.Finalize()
    return plant, ur5, gripper
