"""Inverse kinematics for the UR5 + 2F-85 TCP on Drake's MultibodyPlant:
``SolveTcpIk`` (Drake's ``InverseKinematics`` program, joint limits always
on) and ``NewtonTcpIk`` (Gauss-Newton on the plant's kinematics and
Jacobian, for a target near a known solution: about 10x cheaper, falls back
to the program when it does not converge inside the joint limits)."""
from __future__ import annotations

import dataclasses as dc

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.inverse_kinematics import InverseKinematics
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import JacobianWrtVariable
from pydrake.solvers import Solve


@dc.dataclass
class IkResult:
    """``q``: 6 UR5 joint angles (rad); ``success`` and, if not, ``reason``."""
    q: np.ndarray
    success: bool
    position_error: float
    rotation_error: float
    reason: str = ""


def SolveTcpIk(plant: MultibodyPlant, X_WT: RigidTransform, q_seed: np.ndarray,
               position_tolerance: float = 1e-4, rotation_tolerance: float = 1e-3,
               gripper_half_opening: float = 0.0425) -> IkResult:
    """Joint angles that put the ``tcp`` frame at ``X_WT`` (world frame),
    starting from ``q_seed`` (6). ``plant`` is a controller plant from
    ``MakeControllerPlant`` (8 positions: arm, then the two fingers)."""
    ik = InverseKinematics(plant)
    tcp = plant.GetFrameByName("tcp")
    p = X_WT.translation()
    tol = np.full(3, position_tolerance)
    ik.AddPositionConstraint(tcp, np.zeros(3), plant.world_frame(), p - tol, p + tol)
    ik.AddOrientationConstraint(plant.world_frame(), X_WT.rotation(), tcp,
                                RotationMatrix(), rotation_tolerance)
    q = ik.q()
    prog = ik.get_mutable_prog()
    prog.AddBoundingBoxConstraint(gripper_half_opening, gripper_half_opening, q[6:8])
    q0 = np.concatenate([np.asarray(q_seed, float), [gripper_half_opening] * 2])
    prog.AddQuadraticErrorCost(np.eye(6) * 0.01, q0[:6], q[:6])
    prog.SetInitialGuess(q, q0)
    result = Solve(prog)
    q_sol = result.GetSolution(q)[:6]
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, np.concatenate([q_sol, [gripper_half_opening] * 2]))
    X = plant.CalcRelativeTransform(context, plant.world_frame(), tcp)
    pos_err = float(np.linalg.norm(X.translation() - p))
    rot_err = float(X.rotation().InvertAndCompose(X_WT.rotation()).ToAngleAxis().angle())
    ok = bool(result.is_success()) and pos_err < 10 * position_tolerance + 1e-6
    reason = "" if ok else f"IK failed ({result.get_solver_id().name()}: " \
        f"{result.get_solution_result()}), position error {pos_err:.4f} m"
    return IkResult(q_sol, ok, pos_err, rot_err, reason)


def TcpPose(plant: MultibodyPlant, q: np.ndarray, gripper_half_opening: float = 0.0425
            ) -> RigidTransform:
    """``X_WT`` of the controller plant's ``tcp`` frame at joint angles ``q`` (6)."""
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, np.concatenate([q, [gripper_half_opening] * 2]))
    return plant.CalcRelativeTransform(context, plant.world_frame(),
                                       plant.GetFrameByName("tcp"))


def SolveTcpIkMultiStart(plant: MultibodyPlant, X_WT: RigidTransform, q_seed: np.ndarray,
                         num_random: int = 12, seed: int = 0,
                         gripper_half_opening: float = 0.0425) -> IkResult:
    """``SolveTcpIk`` from ``q_seed``, then from seeded random starts (within
    +-pi) until one succeeds; returns the first success or the last failure."""
    result = SolveTcpIk(plant, X_WT, q_seed, gripper_half_opening=gripper_half_opening)
    rng = np.random.default_rng(seed)
    for _ in range(num_random):
        if result.success:
            break
        start = np.asarray(q_seed, float) + rng.uniform(-np.pi, np.pi, 6)
        start[2] = np.clip(start[2], -np.pi + 0.1, np.pi - 0.1)
        result = SolveTcpIk(plant, X_WT, start, gripper_half_opening=gripper_half_opening)
    return result


def NewtonTcpIk(plant: MultibodyPlant, context, X_WT: RigidTransform, q_seed: np.ndarray,
                gripper_half_opening: float = 0.0, position_tolerance: float = 1e-4,
                rotation_tolerance: float = 1e-3, max_iterations: int = 12) -> IkResult:
    """Joint angles (6) putting the ``tcp`` frame at ``X_WT`` by Gauss-Newton
    steps from ``q_seed`` on ``plant``'s kinematics (``context`` is scratch).
    The TCP's spatial Jacobian is 6x6 and invertible away from
    singularities; each step is a damped least-squares solve, clipped to
    0.5 rad. Succeeds when the position is within ``position_tolerance`` (m)
    and the rotation within ``rotation_tolerance`` (rad) inside the joint
    limits: the same acceptance as ``SolveTcpIk``. From a nearby seed it
    converges to the solution branch of the seed (the one ``SolveTcpIk``'s
    cost toward the seed picks)."""
    world, tcp = plant.world_frame(), plant.GetFrameByName("tcp")
    lo, hi = plant.GetPositionLowerLimits()[:6], plant.GetPositionUpperLimits()[:6]
    p_target, R_target = X_WT.translation(), X_WT.rotation()
    q = np.asarray(q_seed, float).copy()
    grip = [gripper_half_opening] * 2
    pos_err = rot_err = np.inf
    for _ in range(max_iterations):
        plant.SetPositions(context, np.concatenate([q, grip]))
        X = plant.CalcRelativeTransform(context, world, tcp)
        e_p = p_target - X.translation()
        aa = R_target.multiply(X.rotation().inverse()).ToAngleAxis()
        e_r = aa.axis() * aa.angle()        # world-frame rotation still to go
        pos_err, rot_err = float(np.linalg.norm(e_p)), float(aa.angle())
        if pos_err < position_tolerance and rot_err < rotation_tolerance:
            break
        J = plant.CalcJacobianSpatialVelocity(context, JacobianWrtVariable.kQDot, tcp,
                                              np.zeros(3), world, world)[:, :6]
        e = np.concatenate([e_r, e_p])
        dq = np.linalg.solve(J.T @ J + 1e-6 * np.eye(6), J.T @ e)
        step = np.abs(dq).max()
        q = q + (dq * (0.5 / step) if step > 0.5 else dq)
    ok = (pos_err < position_tolerance and rot_err < rotation_tolerance
          and bool(np.all(q >= lo) and np.all(q <= hi)))
    reason = "" if ok else (f"IK failed (Newton: position error {pos_err:.4f} m, "
                            f"rotation error {rot_err:.4f} rad)")
    return IkResult(q, ok, pos_err, rot_err, reason)
