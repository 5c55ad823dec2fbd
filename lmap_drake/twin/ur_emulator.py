"""EMULATOR of a Universal Robots controller for ur_rtde, on loopback. It is
NOT a robot and NOT Universal Robots' URSim: a pure-Python stand-in (standard
library sockets, numpy) that speaks enough of the controller's protocols for
the real ``ur_rtde`` client (PyPI ``ur-rtde`` 1.6.5, modules ``rtde_control``
and ``rtde_receive``) to connect, command and read an emulated UR5.

ur_rtde's Python bindings take only a host name, so the ports are UR's
fixed ones; the emulator binds any loopback address (127.0.0.0/8), so
several emulators (e.g. parallel tests) can run side by side on
127.0.0.2, 127.0.0.3, ... Ports are parameters for other clients.

Run the ur_rtde client in ANOTHER process: its bindings keep the GIL while
they wait for the controller (constructors, moveJ, ...), so an emulator in
the client's process never answers. ``EmulatorProcess`` starts one in a
child process and drives its faults over stdin; ``python -m
lmap_drake.twin.ur_emulator`` serves until Ctrl-C.

Implemented:

- Dashboard server (29999): greeting, ``PolyscopeVersion``, ``get serial
  number``, ``get robot model``, ``robotmode``, ``safetymode``,
  ``safetystatus``, ``programState``, ``running``, ``is in remote control``,
  ``stop`` (always "Stopped": ur_rtde's reconnect fails on the real
  "Failed to execute: stop" of an idle robot), ``play``, ``pause`` (both
  fail: no installed program), ``power on/off``, ``brake release``,
  ``unlock protective stop``, ``close safety popup``, ``close popup``,
  ``popup``, ``restart safety``, ``quit``; others answer "could not
  understand".
- RTDE (30004), protocol version 2: version negotiation, controller version,
  output recipes (every standard output name, see ``OUTPUT_TYPES``) at up
  to the controller rate, input recipes (registers, external wrench, speed
  slider, IO masks), start / pause, data packages both ways, ``IN_USE``
  for inputs another connection owns, text messages are ignored.
- Script port (30003): accepts uploaded programs. A program that is
  ur_rtde's control script (``rtde_control``) is "run" by emulating its
  command table over the RTDE registers (``ControlScript``): the command
  id in ``input_int_register_<off>``, targets in
  ``input_double_register_<off>..``, answers in
  ``output_int_register_<off>`` (1 ready, 2 done), async progress in
  ``output_int_register_<off+2>``; the register offset is read from the
  uploaded script (0, or 24 with ``FLAG_UPPER_RANGE_REGISTERS``; ur_rtde
  1.6.5 writes the value at the start of the line after ``global
  reg_offset_int = # int register offset``). Commands:
  movej (1), movej_ik (2), movel (3), movel_fk (4), speedj (9), servoj
  (11), speed_stop (15), servo_stop (16), set_payload (17), set_tcp (29),
  get_inverse_kin (30, 46), protective_stop (31), stopl (33), stopj (34),
  set_watchdog (35, accepted, not enforced), is_joints_within_safety_limits
  (37), get_tcp_offset (40), get_forward_kin (43, 44), is_steady (47),
  get_actual_tool_flange_pose (58), stop script (255); other ids are
  answered "done" without effect (and logged). While the script runs,
  ``runtime_state`` is PLAYING and ``robot_status_bits`` has "program
  running" set.
- The arm: joint positions follow the commands through ``servo_model``
  (default ``FirstOrderServo``: first-order lag, time constant from servoj's
  lookahead time and gain, 0 for the planned moves, joint speed at most
  pi rad/s) stepped by the emulator's own loop at ``frequency`` (500 Hz as
  an e-Series, 125 Hz as a CB3). movej: synchronised trapezoid in joint
  space; movel: straight line / slerp of the TCP with numeric inverse
  kinematics; TCP pose from the UR5 DH forward kinematics
  (``lmap_drake.robot``) and the set TCP offset.
- Faults (methods and CLI options): ``ProtectiveStop``, ``EmergencyStop``,
  ``DropConnections`` (closes every client socket and refuses new ones for
  ``refuse_s``; the arm stops as on an RTDE watchdog; ur_rtde's control
  interface reconnects by itself once it can), ``SetLatency`` (delays
  inputs and outputs by the given seconds). Each fault zeroes the joint velocities at once and stops the
  control script; the client sees ``isProtectiveStopped`` /
  ``isEmergencyStopped`` / a lost connection. ``UnlockProtectiveStop``
  (dashboard ``unlock protective stop``) and ``ReleaseEmergencyStop`` then
  dashboard ``power on`` / ``brake release`` recover.
- Digital-twin hook: ``q_actual`` / ``qd_actual`` / ``q_command``
  (thread-safe copies), ``SetActual`` and a replaceable ``servo_model``;
  ``SetMeasured`` (or a ``SharedArmState`` in shared memory, ``--shared-state``)
  makes ``actual_q`` / ``actual_qd`` / the actual TCP pose a simulated arm's
  measured joints, while the servo model's joints (``q_servo``) become the
  command that arm tracks: a blocked simulated arm shows in ``getActualQ``.

Not emulated: the primary/secondary/realtime state streams (30001/30002,
and 30003's outgoing data), URScript itself (only ur_rtde's control script's
command table is emulated; other programs are accepted and ignored), force
mode, freedrive, teach mode, contact detection, servoc/servol, speedl,
move paths, IO, the RTDE watchdog, protocol version 1, dynamics (no
torques, currents, masses; no collisions), joint position limits, safety
planes, the 5 s wait before unlocking a protective stop, real timing.
"""
from __future__ import annotations

import argparse
import collections
import dataclasses as dc
import json
import logging
import math
import os
import re
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from typing import Callable

import numpy as np

from lmap_drake.twin.listen import CheckPort, ListenError, ListenHostWarning
from lmap_drake.robot import (UR5_VELOCITY_LIMIT, Ur5DhForwardKinematics,
                                      Ur5DhFrames)

LOG = logging.getLogger("lmap_drake.ur_emulator")

DASHBOARD_PORT, RTDE_PORT, SCRIPT_PORT = 29999, 30004, 30003
E_SERIES_VERSION = (5, 11, 6, 108249)
CB3_VERSION = (3, 15, 8, 106339)
SERIAL_NUMBER = "20000000001"
Q_HOME = (0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0)

# ------------------------------------------------------------------ RTDE types
_TYPE_FORMATS = {"BOOL": "?", "UINT8": "B", "UINT32": "I", "UINT64": "Q", "INT32": "i",
                 "DOUBLE": "d", "VECTOR3D": "3d", "VECTOR6D": "6d", "VECTOR6INT32": "6i",
                 "VECTOR6UINT32": "6I"}
_TYPE_SIZES = {"BOOL": 1, "UINT8": 1, "UINT32": 1, "UINT64": 1, "INT32": 1, "DOUBLE": 1,
               "VECTOR3D": 3, "VECTOR6D": 6, "VECTOR6INT32": 6, "VECTOR6UINT32": 6}


def _Registers(prefix: str, type_: str, indices) -> dict[str, str]:
    return {f"{prefix}{i}": type_ for i in indices}


# Inputs a client may write (CONTROL_PACKAGE_SETUP_INPUTS).
INPUT_TYPES: dict[str, str] = {
    "speed_slider_mask": "UINT32", "speed_slider_fraction": "DOUBLE",
    "standard_digital_output_mask": "UINT8", "standard_digital_output": "UINT8",
    "configurable_digital_output_mask": "UINT8", "configurable_digital_output": "UINT8",
    "tool_digital_output_mask": "UINT8", "tool_digital_output": "UINT8",
    "standard_analog_output_mask": "UINT8", "standard_analog_output_type": "UINT8",
    "standard_analog_output_0": "DOUBLE", "standard_analog_output_1": "DOUBLE",
    "input_bit_registers0_to_31": "UINT32", "input_bit_registers32_to_63": "UINT32",
    "external_force_torque": "VECTOR6D",
    **_Registers("input_bit_register_", "BOOL", range(64, 128)),
    **_Registers("input_int_register_", "INT32", range(48)),
    **_Registers("input_double_register_", "DOUBLE", range(48)),
}

# Outputs a client may read (CONTROL_PACKAGE_SETUP_OUTPUTS); inputs are
# readable too.
OUTPUT_TYPES: dict[str, str] = {
    "timestamp": "DOUBLE",
    **{n: "VECTOR6D" for n in (
        "target_q", "target_qd", "target_qdd", "target_current", "target_moment", "actual_q",
        "actual_qd", "actual_qdd", "actual_current", "actual_current_as_torque",
        "actual_current_window", "actual_moment", "joint_control_output", "actual_TCP_pose",
        "actual_TCP_speed", "actual_TCP_force", "target_TCP_pose", "target_TCP_speed",
        "joint_temperatures", "actual_joint_voltage", "ft_raw_wrench", "payload_inertia",
        "joint_position_deviation_ratio")},
    "actual_digital_input_bits": "UINT64", "actual_digital_output_bits": "UINT64",
    "actual_execution_time": "DOUBLE", "robot_mode": "INT32", "joint_mode": "VECTOR6INT32",
    "safety_mode": "INT32", "safety_status": "INT32", "actual_tool_accelerometer": "VECTOR3D",
    "speed_scaling": "DOUBLE", "target_speed_fraction": "DOUBLE", "actual_momentum": "DOUBLE",
    "actual_main_voltage": "DOUBLE", "actual_robot_voltage": "DOUBLE",
    "actual_robot_current": "DOUBLE", "runtime_state": "UINT32",
    "elbow_position": "VECTOR3D", "elbow_velocity": "VECTOR3D",
    "robot_status_bits": "UINT32", "safety_status_bits": "UINT32", "analog_io_types": "UINT32",
    "standard_analog_input0": "DOUBLE", "standard_analog_input1": "DOUBLE",
    "standard_analog_output0": "DOUBLE", "standard_analog_output1": "DOUBLE",
    "io_current": "DOUBLE", "euromap67_input_bits": "UINT32",
    "euromap67_output_bits": "UINT32", "euromap67_24V_voltage": "DOUBLE",
    "euromap67_24V_current": "DOUBLE", "tool_mode": "UINT32",
    "tool_analog_input_types": "UINT32", "tool_analog_input0": "DOUBLE",
    "tool_analog_input1": "DOUBLE", "tool_output_voltage": "INT32",
    "tool_output_current": "DOUBLE", "tool_temperature": "DOUBLE", "tcp_force_scalar": "DOUBLE",
    "output_bit_registers0_to_31": "UINT32", "output_bit_registers32_to_63": "UINT32",
    "tool_output_mode": "UINT8", "tool_digital_output0_mode": "UINT8",
    "tool_digital_output1_mode": "UINT8", "payload": "DOUBLE", "payload_cog": "VECTOR3D",
    "script_control_line": "UINT32", "collision_detection_ratio": "DOUBLE",
    "time_scale_source": "UINT32",
    **_Registers("output_bit_register_", "BOOL", range(64, 128)),
    **_Registers("output_int_register_", "INT32", range(48)),
    **_Registers("output_double_register_", "DOUBLE", range(48)),
    **INPUT_TYPES,
}

# RTDE package types.
RTDE_REQUEST_PROTOCOL_VERSION = ord("V")
RTDE_GET_URCONTROL_VERSION = ord("v")
RTDE_TEXT_MESSAGE = ord("M")
RTDE_DATA_PACKAGE = ord("U")
RTDE_CONTROL_PACKAGE_SETUP_OUTPUTS = ord("O")
RTDE_CONTROL_PACKAGE_SETUP_INPUTS = ord("I")
RTDE_CONTROL_PACKAGE_START = ord("S")
RTDE_CONTROL_PACKAGE_PAUSE = ord("P")

# Controller state codes (RTDE guide).
ROBOT_MODE_POWER_OFF, ROBOT_MODE_IDLE, ROBOT_MODE_RUNNING = 3, 5, 7
SAFETY_MODE_NORMAL, SAFETY_MODE_PROTECTIVE_STOP, SAFETY_MODE_ROBOT_EMERGENCY_STOP = 1, 3, 7
RUNTIME_STOPPED, RUNTIME_PLAYING = 1, 2
JOINT_MODE_RUNNING, JOINT_MODE_POWER_OFF = 253, 238
ROBOT_STATUS_POWER_ON, ROBOT_STATUS_PROGRAM_RUNNING = 1 << 0, 1 << 1
SAFETY_BIT_NORMAL, SAFETY_BIT_PROTECTIVE_STOPPED = 1 << 0, 1 << 2
SAFETY_BIT_ROBOT_EMERGENCY_STOPPED, SAFETY_BIT_EMERGENCY_STOPPED = 1 << 6, 1 << 7
SAFETY_BIT_STOPPED_DUE_TO_SAFETY = 1 << 10

ROBOT_MODE_NAMES = {3: "POWER_OFF", 5: "IDLE", 7: "RUNNING"}
SAFETY_MODE_NAMES = {1: "NORMAL", 3: "PROTECTIVE_STOP", 7: "ROBOT_EMERGENCY_STOP"}

# ur_rtde control script: command ids (its rtde_control.script) and the ones
# its main loop treats as real-time (processed every cycle, answer "ready").
CMD_NAMES = {0: "no_cmd", 1: "movej", 2: "movej_ik", 3: "movel", 4: "movel_fk", 5: "movec",
             6: "force_mode", 7: "force_mode_stop", 8: "zero_ftsensor", 9: "speedj",
             10: "speedl", 11: "servoj", 12: "servoc", 15: "speed_stop", 16: "servo_stop",
             17: "set_payload", 18: "teach_mode", 19: "end_teach_mode", 24: "servol",
             29: "set_tcp", 30: "get_inverse_kin_args", 31: "protective_stop", 33: "stopl",
             34: "stopj", 35: "set_watchdog", 37: "is_joints_within_safety_limits",
             40: "get_tcp_offset", 43: "get_forward_kin_default", 44: "get_forward_kin_args",
             46: "get_inverse_kin_default", 47: "is_steady",
             58: "get_actual_tool_flange_pose", 255: "stop_script"}
REALTIME_CMDS = frozenset({24, 11, 9, 10, 6, 25, 26, 27, 38, 58, 66, 67, 68, 69, 70, 71})
SCRIPT_READY, SCRIPT_DONE = 1, 2


# ------------------------------------------------------------------ kinematics
def RotationToRotvec(R: np.ndarray) -> np.ndarray:
    """Axis-angle vector (UR's rx, ry, rz) of a rotation matrix."""
    cos = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    angle = math.acos(cos)
    if angle < 1e-9:
        return np.zeros(3)
    if angle > math.pi - 1e-6:  # axis from the symmetric part
        axis = np.sqrt(np.maximum((np.diag(R) + 1.0) / 2.0, 0.0))
        k = int(np.argmax(axis))
        for j in range(3):
            if j != k:
                axis[j] = math.copysign(axis[j], R[k, j] + R[j, k])
        return angle * axis / np.linalg.norm(axis)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return angle * w / (2.0 * math.sin(angle))


def RotvecToRotation(r) -> np.ndarray:
    """Rotation matrix of an axis-angle vector (Rodrigues)."""
    r = np.asarray(r, float)
    angle = float(np.linalg.norm(r))
    if angle < 1e-12:
        return np.eye(3)
    k = r / angle
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def PoseToTransform(pose) -> np.ndarray:
    """4x4 transform of a UR pose [x, y, z, rx, ry, rz]."""
    T = np.eye(4)
    T[:3, :3] = RotvecToRotation(pose[3:6])
    T[:3, 3] = pose[:3]
    return T


def TransformToPose(T: np.ndarray) -> np.ndarray:
    return np.concatenate([T[:3, 3], RotationToRotvec(T[:3, :3])])


def TcpTransform(q, tcp_offset=np.zeros(6)) -> np.ndarray:
    """Base-frame transform of the TCP: UR5 DH flange pose times the TCP
    offset (a UR pose in the flange frame)."""
    return Ur5DhForwardKinematics(np.asarray(q, float)) @ PoseToTransform(tcp_offset)


def TcpJacobian(q, tcp_offset=np.zeros(6)) -> np.ndarray:
    """6x6 geometric Jacobian of the TCP (linear rows first), base frame."""
    frames = Ur5DhFrames(q)
    p_tcp = (frames[6] @ PoseToTransform(tcp_offset))[:3, 3]
    J = np.zeros((6, 6))
    for i in range(6):
        z, p = frames[i][:3, 2], frames[i][:3, 3]
        J[:3, i] = np.cross(z, p_tcp - p)
        J[3:, i] = z
    return J


def _PoseError(T_goal: np.ndarray, T: np.ndarray) -> np.ndarray:
    return np.concatenate([T_goal[:3, 3] - T[:3, 3],
                           RotationToRotvec(T_goal[:3, :3] @ T[:3, :3].T)])


def InverseKinematics(T_goal: np.ndarray, q_near, tcp_offset=np.zeros(6),
                      iterations: int = 100, tol: float = 1e-14) -> np.ndarray | None:
    """Joint positions near ``q_near`` whose TCP is at ``T_goal`` (damped
    least squares), or None when it does not converge."""
    q = np.array(q_near, float)
    for _ in range(iterations):
        err = _PoseError(T_goal, TcpTransform(q, tcp_offset))
        if float(err @ err) < tol:
            return q
        J = TcpJacobian(q, tcp_offset)
        dq = J.T @ np.linalg.solve(J @ J.T + 1e-6 * np.eye(6), err)
        scale = max(1.0, float(np.abs(dq).max()) / 0.5)  # at most 0.5 rad a step
        q = q + dq / scale
    err = _PoseError(T_goal, TcpTransform(q, tcp_offset))
    return q if float(err @ err) < 1e-10 else None


# ------------------------------------------------------------------ servo model
ServoModel = Callable[[np.ndarray, np.ndarray, np.ndarray, float, float],
                      tuple[np.ndarray, np.ndarray]]


def FirstOrderServo(q, qd, q_ref, dt: float, tau: float,
                    v_max: float = UR5_VELOCITY_LIMIT) -> tuple[np.ndarray, np.ndarray]:
    """One step of the default joint servo: velocity (q_ref - q) / tau (tau
    at least dt, so tau 0 reaches q_ref when the speed allows), at most
    ``v_max`` per joint. Returns (q, qd)."""
    v = np.clip((q_ref - q) / max(tau, dt), -v_max, v_max)
    return q + v * dt, v


def ServojTimeConstant(lookahead_time: float, gain: float) -> float:
    """Lag of the emulated servoj: lookahead_time * 300 / gain, within
    [0.002, 0.2] s (a rough model: longer lookahead and lower gain lag more)."""
    if not (lookahead_time > 0 and gain > 0):
        return 0.1
    return float(np.clip(lookahead_time * 300.0 / gain, 0.002, 0.2))


def _Trapezoid(distance: float, v: float, a: float) -> tuple[float, Callable[[float], float]]:
    """(duration, s(t)) of a rest-to-rest trapezoid covering ``distance``."""
    v, a = max(v, 1e-6), max(a, 1e-6)
    if distance <= 1e-12:
        return 0.0, lambda t: distance
    t_acc = v / a
    if a * t_acc * t_acc >= distance:  # triangle
        t_acc = math.sqrt(distance / a)
        v = a * t_acc
        t_flat = 0.0
    else:
        t_flat = (distance - a * t_acc * t_acc) / v
    T = 2 * t_acc + t_flat

    def s(t: float) -> float:
        t = min(max(t, 0.0), T)
        if t < t_acc:
            return 0.5 * a * t * t
        if t < t_acc + t_flat:
            return 0.5 * a * t_acc * t_acc + v * (t - t_acc)
        tr = T - t
        return distance - 0.5 * a * tr * tr
    return T, s


# ------------------------------------------------------------------ the arm
@dc.dataclass
class _Motion:
    """What the arm is doing: ``kind`` in idle, servo, speed, movej, movel,
    stop, halted."""
    kind: str = "idle"
    t0: float = 0.0
    duration: float = 0.0
    profile: Callable | None = None  # t -> q_ref (movej, movel) or None
    servo_target: np.ndarray | None = None
    tau: float = 0.0
    speed_target: np.ndarray | None = None
    accel: float = 1.0
    failed: str | None = None  # movel IK failure


class EmulatedArm:
    """Joint state of the emulated UR5 and its motion generators. Not
    thread-safe by itself: ``UrEmulator`` calls it under its lock."""

    def __init__(self, q0, servo_model: ServoModel = FirstOrderServo):
        self.q = np.array(q0, float)
        self.qd = np.zeros(6)
        self.qdd = np.zeros(6)
        self.q_ref = self.q.copy()
        self.qd_ref = np.zeros(6)
        self.tcp_offset = np.zeros(6)
        self.servo_model = servo_model
        self.motion = _Motion()
        self.time = 0.0
        self.settle_tolerance = 1e-4  # rad: a move is done when this close to its goal

    def Hold(self, kind: str = "idle") -> None:
        """Stops at once (velocity zero) and holds the current position."""
        self.motion = _Motion(kind=kind)
        self.qd[:] = 0.0
        self.q_ref = self.q.copy()
        self.qd_ref = np.zeros(6)

    def Servo(self, q_target, lookahead_time: float, gain: float) -> None:
        if self.motion.kind != "servo":
            self.motion = _Motion(kind="servo")
        self.motion.servo_target = np.array(q_target, float)
        self.motion.tau = ServojTimeConstant(lookahead_time, gain)

    def Speed(self, qd_target, accel: float) -> None:
        if self.motion.kind != "speed":
            self.motion = _Motion(kind="speed")
            self.qd_ref = self.qd.copy()
        self.motion.speed_target = np.clip(np.array(qd_target, float), -UR5_VELOCITY_LIMIT,
                                           UR5_VELOCITY_LIMIT)
        self.motion.accel = max(float(accel), 1e-3)

    def Stop(self, decel: float) -> None:
        """Decelerates every joint at ``decel`` (rad/s^2; stopl's m/s^2 is
        taken as rad/s^2) to rest."""
        self.motion = _Motion(kind="stop", accel=max(float(decel), 1e-3))
        self.qd_ref = self.qd.copy()

    def MoveJ(self, q_goal, v: float, a: float) -> None:
        q0, q1 = self.q.copy(), np.array(q_goal, float)
        d = q1 - q0
        dist = float(np.abs(d).max())
        T, s = _Trapezoid(dist, min(v, UR5_VELOCITY_LIMIT), a)
        self.motion = _Motion(kind="movej", t0=self.time, duration=T,
                              profile=lambda t: q1 if dist <= 1e-12 else q0 + d * (s(t) / dist))

    def MoveL(self, T_goal: np.ndarray, v: float, a: float) -> None:
        T0 = TcpTransform(self.q, self.tcp_offset)
        dp = T_goal[:3, 3] - T0[:3, 3]
        rot = RotationToRotvec(T0[:3, :3].T @ T_goal[:3, :3])  # in the start TCP frame
        length, angle = float(np.linalg.norm(dp)), float(np.linalg.norm(rot))
        dist = length if length > 1e-6 else angle
        T, s = _Trapezoid(dist, v, a)
        q_start = self.q.copy()
        state = {"q": q_start}

        def profile(t: float):
            f = 1.0 if dist <= 1e-12 else s(t) / dist
            Tt = np.eye(4)
            Tt[:3, 3] = T0[:3, 3] + f * dp
            Tt[:3, :3] = T0[:3, :3] @ RotvecToRotation(f * rot)
            q = InverseKinematics(Tt, state["q"], self.tcp_offset, iterations=20)
            if q is None:
                return None
            state["q"] = q
            return q
        self.motion = _Motion(kind="movel", t0=self.time, duration=T, profile=profile)

    @property
    def moving(self) -> bool:
        """True while a move (its profile, then settling within
        ``settle_tolerance``) or a stop runs, and while servoing / speeding."""
        m = self.motion
        if m.kind in ("movej", "movel"):
            return m.failed is None and (
                self.time - m.t0 < m.duration
                or float(np.abs(self.q - self.q_ref).max()) > self.settle_tolerance)
        if m.kind == "stop":
            return bool(np.any(self.qd_ref != 0.0))
        return m.kind in ("servo", "speed")

    def Step(self, dt: float) -> None:
        """Advances the arm by ``dt`` seconds."""
        m = self.motion
        self.time += dt
        tau = 0.0
        if m.kind == "servo":
            self.q_ref = m.servo_target.copy()
            tau = m.tau
        elif m.kind in ("speed", "stop"):
            goal = m.speed_target if m.kind == "speed" else np.zeros(6)
            step = m.accel * dt
            self.qd_ref = self.qd_ref + np.clip(goal - self.qd_ref, -step, step)
            self.q_ref = self.q + self.qd_ref * dt
        elif m.kind in ("movej", "movel") and m.failed is None:
            q = m.profile(self.time - m.t0)
            if q is None:
                self.Hold("halted")
                self.motion.failed = "inverse kinematics failed on the movel path"
                return
            self.q_ref = q
        else:  # idle, halted
            self.q_ref = self.q.copy()
        qd_old = self.qd
        q, qd = self.servo_model(self.q, self.qd, self.q_ref, dt, tau)
        self.q, self.qd = np.asarray(q, float), np.asarray(qd, float)
        self.qdd = (self.qd - qd_old) / dt
        if m.kind == "stop":
            self.qd = np.where(self.qd_ref == 0.0, 0.0, self.qd)


# ------------------------------------------------------------------ control script
class ControlScript:
    """The controller side of ur_rtde's control script: its main loop and
    command table over the RTDE registers (see the module docstring)."""

    def __init__(self, emu: "UrEmulator", reg_offset_int: int = 0, reg_offset_float: int = 0):
        self.emu = emu
        self.oi, self.of = reg_offset_int, reg_offset_float
        self.running = True
        self.executing_cmd = False
        self.blocking: int | None = None  # command waiting for its motion
        self.async_wr_count = 0
        self.async_op_id = 0
        self.async_motion = False
        self.commands_seen: collections.Counter = collections.Counter()  # real-time: per cycle
        self._ResetAsyncProgress()
        self._WriteInt(0, SCRIPT_READY)

    # registers (offset like the script's read_input_*_reg / write_output_*_reg)
    def _Int(self, i: int) -> int:
        return int(self.emu.registers[f"input_int_register_{i + self.oi}"])

    def _Float(self, i: int) -> float:
        return float(self.emu.registers[f"input_double_register_{i + self.of}"])

    def _Floats(self, i: int, n: int = 6) -> np.ndarray:
        return np.array([self._Float(i + k) for k in range(n)])

    def _WriteInt(self, i: int, v: int) -> None:
        self.emu.registers[f"output_int_register_{i + self.oi}"] = int(v)

    def _WriteFloats(self, i: int, values) -> None:
        for k, v in enumerate(values):
            self.emu.registers[f"output_double_register_{i + k + self.of}"] = float(v)

    def _WriteAsyncProgress(self, value: int) -> None:
        self.async_wr_count = (self.async_wr_count + 1) % 128
        if value == 0:
            self.async_op_id = (self.async_op_id + 1) % 128
        reg = self.async_wr_count * 65536 + self.async_op_id * 16777216
        if value >= 0:
            reg += min(value, 32767) + 32768
        self._WriteInt(2, reg)

    def _ResetAsyncProgress(self) -> None:
        self._WriteAsyncProgress(-1)

    # main loop
    def Tick(self) -> None:
        """One controller cycle of the script's main loop."""
        if not self.running:
            return
        arm = self.emu.arm
        if arm.motion.failed:
            self.Terminate(f"control script halted: {arm.motion.failed}")
            return
        if self.async_motion and not arm.moving:
            self.async_motion = False
            self._WriteAsyncProgress(-1)
        if self.blocking is not None:  # a synchronous move runs
            if arm.moving:
                return
            self.blocking = None
            self._WriteInt(0, SCRIPT_DONE)
            return
        cmd = self._Int(0)
        if cmd in REALTIME_CMDS:
            self._Process(cmd)
            self._WriteInt(0, SCRIPT_READY)
        elif cmd == 0:
            self.executing_cmd = False
            self._WriteInt(0, SCRIPT_READY)
        else:
            if not self.executing_cmd:
                self._Process(cmd)
            self.executing_cmd = True

    def Terminate(self, reason: str) -> None:
        if self.running:
            LOG.info("%s", reason)
        self.running = False
        self.blocking = None

    def _Move(self, cmd: int, start: Callable[[], None]) -> None:
        """Starts a move; synchronous moves answer "done" when it ends."""
        asynchronous = self._Int(1) == 1
        if self.async_motion:  # stop_async_move
            self.async_motion = False
            self._WriteAsyncProgress(-1)
        start()
        if asynchronous:
            self.async_motion = True
            self._WriteAsyncProgress(0)
            self._WriteInt(0, SCRIPT_DONE)
        else:
            self.blocking = cmd

    def _Process(self, cmd: int) -> None:
        emu, arm = self.emu, self.emu.arm
        self.commands_seen[cmd] += 1
        if cmd not in REALTIME_CMDS:
            LOG.debug("control script: command %d (%s)", cmd, CMD_NAMES.get(cmd, "?"))
        if cmd == 255:
            arm.Stop(20.0)
            self.Terminate("control script: stop script received")
            return
        v, a = self._Float(6), self._Float(7)
        if cmd == 1:  # movej
            return self._Move(cmd, lambda: arm.MoveJ(self._Floats(0), v, a))
        if cmd == 2:  # movej_ik
            q = InverseKinematics(PoseToTransform(self._Floats(0)), arm.q, arm.tcp_offset)
            if q is None:
                return self.Terminate("control script halted: movej_ik: no IK solution")
            return self._Move(cmd, lambda: arm.MoveJ(q, v, a))
        if cmd == 3:  # movel
            T = PoseToTransform(self._Floats(0))
            if InverseKinematics(T, arm.q, arm.tcp_offset) is None:  # checked before moving
                return self.Terminate("control script halted: movel: target pose not reachable")
            return self._Move(cmd, lambda: arm.MoveL(T, v, a))
        if cmd == 4:  # movel_fk
            T = TcpTransform(self._Floats(0), arm.tcp_offset)
            return self._Move(cmd, lambda: arm.MoveL(T, v, a))
        if cmd == 9:  # speedj: qd, acceleration in 6, time in 7
            arm.Speed(self._Floats(0), self._Float(6))
        elif cmd == 11:  # servoj: q, v, a, time 8, lookahead 9, gain 10
            arm.Servo(self._Floats(0), self._Float(9), self._Float(10))
        elif cmd in (15, 16, 33, 34):  # speed_stop, servo_stop, stopl, stopj
            arm.Stop(self._Float(0))
            if cmd in (33, 34) and self._Int(1) == 1:
                self._WriteAsyncProgress(0)
                self.async_motion = True
            else:
                self.blocking = cmd
                return
        elif cmd == 29:  # set_tcp
            arm.tcp_offset = self._Floats(0)
        elif cmd in (30, 46):  # get_inverse_kin (args / default)
            q_near = self._Floats(6) if cmd == 30 else arm.q
            q = InverseKinematics(PoseToTransform(self._Floats(0)), q_near, arm.tcp_offset)
            self._WriteFloats(0, q if q is not None else q_near)
        elif cmd == 31:  # protective_stop
            emu._ProtectiveStopLocked("protective stop requested by the client")
            return
        elif cmd == 37:  # is_joints_within_safety_limits: +-2 pi
            self._WriteInt(1, int(bool(np.all(np.abs(self._Floats(0)) <= 2 * math.pi))))
        elif cmd == 40:  # get_tcp_offset
            self._WriteFloats(0, arm.tcp_offset)
        elif cmd in (43, 44):  # get_forward_kin default / args
            q, tcp = (self.emu.actual[0], arm.tcp_offset) if cmd == 43 else (self._Floats(0),
                                                                 self._Floats(6))
            self._WriteFloats(0, TransformToPose(TcpTransform(q, tcp)))
        elif cmd == 47:  # is_steady
            self._WriteInt(1, int(not np.any(np.abs(arm.qd) > 1e-4)))
        elif cmd == 58:  # get_actual_tool_flange_pose
            self._WriteFloats(0, TransformToPose(Ur5DhForwardKinematics(self.emu.actual[0])))
        elif cmd in CMD_NAMES and cmd not in (17, 35):
            LOG.warning("control script: command %d (%s) is not emulated; answered done",
                        cmd, CMD_NAMES[cmd])
        elif cmd not in CMD_NAMES:
            LOG.warning("control script: unknown command %d; answered done", cmd)
        self._WriteInt(0, SCRIPT_DONE)


# ------------------------------------------------------------------ connections
class _Connection:
    """One accepted client socket; ``Close`` is idempotent and thread-safe."""

    def __init__(self, sock: socket.socket, kind: str):
        self.sock = sock
        self.kind = kind
        self.send_lock = threading.Lock()
        self.closed = False

    def Send(self, data: bytes) -> bool:
        with self.send_lock:
            if self.closed:
                return False
            try:
                self.sock.sendall(data)
                return True
            except OSError:
                self.Close()
                return False

    def RecvExact(self, n: int) -> bytes | None:
        buf = b""
        while len(buf) < n:
            try:
                chunk = self.sock.recv(n - len(buf))
            except OSError:
                return None
            if not chunk:
                return None
            buf += chunk
        return buf

    def Close(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.sock.close()


@dc.dataclass
class _OutputRecipe:
    recipe_id: int
    names: list[str]
    fmt: struct.Struct
    period_ticks: int


class _RtdeConnection(_Connection):
    def __init__(self, sock, emu: "UrEmulator"):
        super().__init__(sock, "rtde")
        self.emu = emu
        self.protocol_version = 1
        self.outputs: _OutputRecipe | None = None
        self.inputs: dict[int, tuple[list[str], struct.Struct]] = {}
        self.started = False
        self.next_output_id = 1  # output and input recipes are numbered apart
        self.next_input_id = 1
        self.tick_phase = 0

    def SendPackage(self, ptype: int, payload: bytes = b"") -> bool:
        return self.Send(struct.pack(">HB", len(payload) + 3, ptype) + payload)


class _ServerSocket:
    """A listening socket with an accept thread that hands each client to
    ``handler(sock)`` in its own daemon thread."""

    def __init__(self, host: str, port: int, name: str, handler):
        self.name = name
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self.sock.bind((host, port))
        except OSError as err:
            self.sock.close()
            raise OSError(err.errno, f"UR emulator: cannot bind the {name} port {host}:{port} "
                                     f"({err.strerror}); is another emulator or robot "
                                     f"software using it? Use another loopback host "
                                     f"(e.g. 127.0.0.2)") from err
        self.sock.listen(8)
        self.port = self.sock.getsockname()[1]
        self.handler = handler
        self.thread = threading.Thread(target=self._Accept, name=f"ur_emu_{name}_accept",
                                       daemon=True)
        self.thread.start()

    def _Accept(self) -> None:
        while True:
            try:
                client, _ = self.sock.accept()
            except OSError:
                return
            client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            threading.Thread(target=self.handler, args=(client,), daemon=True,
                             name=f"ur_emu_{self.name}_client").start()

    def Close(self) -> None:
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.sock.close()


# ------------------------------------------------------------------ the emulator
class UrEmulator:
    """A loopback UR controller emulator (dashboard, RTDE, script port) with
    an emulated UR5; see the module docstring. Use as a context manager or
    call ``Start`` / ``Close``.

    ``host`` is a loopback address (another one only with ``allow_remote``:
    these ports control the arm without authentication); ``frequency`` the controller loop and the
    highest RTDE output rate (default 500 Hz for an e-Series version, 125 Hz
    for a CB3 ``controller_version`` such as ``CB3_VERSION``); ``latency``
    (s) delays every input and output; ``servo_model`` replaces
    ``FirstOrderServo`` (signature ``(q, qd, q_ref, dt, tau) -> (q, qd)``)."""

    def __init__(self, host: str = "127.0.0.1", q0=Q_HOME, *,
                 dashboard_port: int = DASHBOARD_PORT, rtde_port: int = RTDE_PORT,
                 script_port: int = SCRIPT_PORT, controller_version=E_SERIES_VERSION,
                 frequency: float | None = None, latency: float = 0.0,
                 servo_model: ServoModel = FirstOrderServo, robot_model: str = "UR5",
                 serial_number: str = SERIAL_NUMBER, allow_remote: bool = False):
        self.listen_warning = ListenHostWarning(host, allow_remote)   # ListenError first
        self.host = host
        self.ports = {"dashboard": dashboard_port, "rtde": rtde_port, "script": script_port}
        self.controller_version = tuple(int(v) for v in controller_version)
        e_series = self.controller_version[0] >= 5
        self.frequency = float(frequency or (500.0 if e_series else 125.0))
        self.robot_model = robot_model
        self.serial_number = serial_number
        self._lock = threading.RLock()
        self.arm = EmulatedArm(q0, servo_model)
        self.registers: dict[str, float] = {
            n: 0 for n in OUTPUT_TYPES if n.startswith(("input_int", "input_double", "output_int",
                                                         "output_double"))}
        self.values: dict[str, object] = {}  # other inputs written by clients
        self.script: ControlScript | None = None
        self.latency = float(latency)
        self.powered = True
        self.protective_stopped = False
        self.emergency_stopped = False
        self.fault_log: list[str] = []
        self.programs: list[str] = []  # every program received on the script port
        self.dashboard_log: list[str] = []
        self._connections: set[_Connection] = set()
        self._input_owner: dict[str, _RtdeConnection] = {}
        self._pending_inputs: collections.deque = collections.deque()
        self._history: collections.deque = collections.deque()
        self._servers: list[_ServerSocket] = []
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._refuse_until = 0.0
        self._t_start = time.monotonic()
        self._measured: tuple[np.ndarray, np.ndarray] | None = None  # a simulated arm's (q, qd)
        self._tcp_force = np.zeros(3)   # N: a simulated arm's wrist force (actual_TCP_force)
        self._shared: SharedArmState | None = None
        self.stats = {"ticks": 0, "late_ticks": 0, "max_late_s": 0.0, "packages_sent": 0,
                      "packages_received": 0}

    # ---- lifecycle -----------------------------------------------------------
    def Start(self) -> "UrEmulator":
        """Binds the three ports and starts the controller loop."""
        handlers = {"dashboard": self._ServeDashboard, "rtde": self._ServeRtde,
                    "script": self._ServeScript}
        try:
            for name, port in self.ports.items():
                self._servers.append(_ServerSocket(self.host, port, name, handlers[name]))
        except OSError:
            self.Close()
            raise
        self.ports = {s.name: s.port for s in self._servers}
        self._t_start = time.monotonic()
        self._thread = threading.Thread(target=self._Loop, name="ur_emu_controller", daemon=True)
        self._thread.start()
        LOG.info("UR emulator on %s: dashboard %d, RTDE %d, script %d, %.0f Hz", self.host,
                 self.ports["dashboard"], self.ports["rtde"], self.ports["script"],
                 self.frequency)
        return self

    def Close(self) -> None:
        """Stops the loop, closes every socket (idempotent)."""
        self._stop.set()
        for s in self._servers:
            s.Close()
        self._servers = []
        self._CloseConnections()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        if self._shared is not None and (self._thread is None or not self._thread.is_alive()):
            self._shared.Close()
            self._shared = None

    def __enter__(self) -> "UrEmulator":
        return self.Start()

    def __exit__(self, *exc) -> None:
        self.Close()

    # ---- digital-twin hook ---------------------------------------------------
    @property
    def actual(self) -> tuple[np.ndarray, np.ndarray]:
        """(q, qd) the controller reports: a simulated arm's measured joints
        once ``SetMeasured`` (or the shared state) gave them, else the servo
        model's."""
        return self._measured if self._measured is not None else (self.arm.q, self.arm.qd)

    @property
    def q_actual(self) -> np.ndarray:
        with self._lock:
            return self.actual[0].copy()

    @property
    def qd_actual(self) -> np.ndarray:
        with self._lock:
            return self.actual[1].copy()

    @property
    def q_servo(self) -> np.ndarray:
        """The servo model's joints: the command a simulated arm tracks."""
        with self._lock:
            return self.arm.q.copy()

    def SetMeasured(self, q, qd=None, tcp_force=None) -> None:
        """A simulated arm's measured joints (rad, rad/s): reported from now
        on as ``actual_q`` / ``actual_qd`` (None: the servo model's again);
        ``tcp_force`` (3, N): its wrist force, reported as the force part of
        ``actual_TCP_force`` (None: unchanged)."""
        with self._lock:
            if tcp_force is not None:
                self._tcp_force = np.array(tcp_force, float).reshape(3)
            self._measured = None if q is None else (
                np.array(q, float), np.zeros(6) if qd is None else np.array(qd, float))

    def AttachSharedState(self, name: str) -> None:
        """Exchanges the arm's state with a twin through the shared memory
        block ``name`` (see ``SharedArmState``) every controller cycle."""
        self._shared = SharedArmState(name)

    @property
    def q_command(self) -> np.ndarray:
        """The joint reference the servo tracks this cycle."""
        with self._lock:
            return self.arm.q_ref.copy()

    @property
    def motion_kind(self) -> str:
        with self._lock:
            return self.arm.motion.kind

    @property
    def script_running(self) -> bool:
        with self._lock:
            return self.script is not None and self.script.running

    def SetActual(self, q, qd=None) -> None:
        """Overwrites the measured joint state (e.g. from a simulation)."""
        with self._lock:
            self.arm.q = np.array(q, float)
            self.arm.qd = np.zeros(6) if qd is None else np.array(qd, float)

    @property
    def servo_model(self) -> ServoModel:
        return self.arm.servo_model

    @servo_model.setter
    def servo_model(self, model: ServoModel) -> None:
        with self._lock:
            self.arm.servo_model = model

    # ---- faults --------------------------------------------------------------
    def _StopScriptLocked(self, reason: str) -> None:
        if self.script is not None:
            self.script.Terminate(reason)

    def _ProtectiveStopLocked(self, reason: str) -> None:
        self.protective_stopped = True
        self.arm.Hold("halted")
        self._StopScriptLocked(f"control script stopped: {reason}")
        self.fault_log.append(f"protective stop: {reason}")
        LOG.warning("protective stop: %s", reason)

    def ProtectiveStop(self, reason: str = "injected") -> None:
        """Protective stop: the arm stops at once, the script stops, the
        safety status shows it until ``UnlockProtectiveStop``."""
        with self._lock:
            self._ProtectiveStopLocked(reason)

    def UnlockProtectiveStop(self) -> None:
        with self._lock:
            self.protective_stopped = False

    def EmergencyStop(self, reason: str = "injected") -> None:
        """Emergency stop: the arm stops at once and powers off, the script
        stops, until ``ReleaseEmergencyStop`` and dashboard power on."""
        with self._lock:
            self.emergency_stopped = True
            self.powered = False
            self.arm.Hold("halted")
            self._StopScriptLocked(f"control script stopped: emergency stop ({reason})")
            self.fault_log.append(f"emergency stop: {reason}")
            LOG.warning("emergency stop: %s", reason)

    def ReleaseEmergencyStop(self) -> None:
        with self._lock:
            self.emergency_stopped = False

    def DropConnections(self, reason: str = "injected", refuse_s: float = 0.0) -> None:
        """Closes every client socket (dashboard, RTDE, script) and closes new
        ones at once for ``refuse_s`` seconds (a pulled cable: ur_rtde's
        control interface otherwise reconnects at once); the arm stops at
        once and the script stops, as an RTDE watchdog would."""
        with self._lock:
            self.arm.Hold("halted")
            self._StopScriptLocked(f"control script stopped: connections dropped ({reason})")
            self.fault_log.append(f"dropped connections: {reason}")
            self._refuse_until = time.monotonic() + max(0.0, float(refuse_s))
        LOG.warning("dropping every connection: %s (refusing new ones for %.2f s)", reason,
                    refuse_s)
        self._CloseConnections()

    def SetLatency(self, seconds: float) -> None:
        """Delays every later input and output by ``seconds``."""
        with self._lock:
            self.latency = max(0.0, float(seconds))
            self.fault_log.append(f"latency {self.latency:.3f} s")

    def _CloseConnections(self) -> None:
        with self._lock:
            conns = list(self._connections)
        for c in conns:
            c.Close()

    # ---- controller state ----------------------------------------------------
    def _RobotMode(self) -> int:
        return ROBOT_MODE_RUNNING if self.powered else ROBOT_MODE_POWER_OFF

    def _SafetyMode(self) -> int:
        if self.emergency_stopped:
            return SAFETY_MODE_ROBOT_EMERGENCY_STOP
        if self.protective_stopped:
            return SAFETY_MODE_PROTECTIVE_STOP
        return SAFETY_MODE_NORMAL

    def _SafetyBits(self) -> int:
        bits = 0
        if self.emergency_stopped:
            bits |= (SAFETY_BIT_ROBOT_EMERGENCY_STOPPED | SAFETY_BIT_EMERGENCY_STOPPED
                     | SAFETY_BIT_STOPPED_DUE_TO_SAFETY)
        if self.protective_stopped:
            bits |= SAFETY_BIT_PROTECTIVE_STOPPED | SAFETY_BIT_STOPPED_DUE_TO_SAFETY
        return bits or SAFETY_BIT_NORMAL

    def _Snapshot(self, now: float) -> dict:
        """Values of the computed outputs at this cycle."""
        arm = self.arm
        q, qd = self.actual
        running = self.script is not None and self.script.running
        T = TcpTransform(q, arm.tcp_offset)
        T_ref = TcpTransform(arm.q_ref, arm.tcp_offset)
        tcp_speed = TcpJacobian(q, arm.tcp_offset) @ qd
        frames = Ur5DhFrames(q)
        joint_mode = JOINT_MODE_RUNNING if self.powered else JOINT_MODE_POWER_OFF
        snap = {
            "timestamp": now - self._t_start,
            "target_q": tuple(arm.q_ref), "target_qd": tuple(arm.qd), "target_qdd": tuple(arm.qdd),
            "actual_q": tuple(q), "actual_qd": tuple(qd), "actual_qdd": tuple(arm.qdd),
            "actual_TCP_pose": tuple(TransformToPose(T)),
            "target_TCP_pose": tuple(TransformToPose(T_ref)),
            "actual_TCP_speed": tuple(tcp_speed), "target_TCP_speed": tuple(tcp_speed),
            "actual_TCP_force": (*self._tcp_force.tolist(), 0.0, 0.0, 0.0),
            "joint_temperatures": (30.0,) * 6, "actual_joint_voltage": (48.0,) * 6,
            "robot_mode": self._RobotMode(), "joint_mode": (joint_mode,) * 6,
            "safety_mode": self._SafetyMode(), "safety_status": self._SafetyMode(),
            "speed_scaling": 1.0, "target_speed_fraction": 1.0,
            "actual_main_voltage": 48.0, "actual_robot_voltage": 48.0 if self.powered else 0.0,
            "runtime_state": RUNTIME_PLAYING if running else RUNTIME_STOPPED,
            "elbow_position": tuple(frames[3][:3, 3]), "elbow_velocity": (0.0, 0.0, 0.0),
            "robot_status_bits": ((ROBOT_STATUS_POWER_ON if self.powered else 0)
                                  | (ROBOT_STATUS_PROGRAM_RUNNING if running else 0)),
            "safety_status_bits": self._SafetyBits(),
            "actual_tool_accelerometer": (0.0, 0.0, 9.81), "tool_temperature": 35.0,
            "actual_execution_time": 0.1, "payload": 0.0,
        }
        snap.update(self.registers)
        snap.update(self.values)
        return snap

    # ---- controller loop -----------------------------------------------------
    def _Loop(self) -> None:
        dt = 1.0 / self.frequency
        t_next = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            if now < t_next:
                time.sleep(t_next - now)
                now = time.monotonic()
            late = now - t_next
            self.stats["ticks"] += 1
            self.stats["max_late_s"] = max(self.stats["max_late_s"], late)
            if late > dt:
                self.stats["late_ticks"] += 1
                t_next = now  # do not try to catch up
            t_next += dt
            try:
                self._Tick(now, dt)
            except Exception:  # keep serving; the log says what broke
                LOG.exception("UR emulator: controller cycle failed")

    def _Tick(self, now: float, dt: float) -> None:
        with self._lock:
            while self._pending_inputs and self._pending_inputs[0][0] <= now:
                _, updates = self._pending_inputs.popleft()
                for name, value in updates:
                    if name in self.registers:
                        self.registers[name] = value
                    else:
                        self.values[name] = value
            if self.script is not None:
                self.script.Tick()
            if self.protective_stopped or self.emergency_stopped or not self.powered:
                if self.arm.motion.kind != "halted":
                    self.arm.Hold("halted")
            self.arm.Step(dt)
            if self._shared is not None:
                measured = self._shared.ReadMeasured()
                if measured is not None:
                    self._measured, self._tcp_force = measured[:2], measured[2]
                self._shared.WriteServo(self.arm.q, self.protective_stopped,
                                        self.emergency_stopped)
            conns = [c for c in self._connections
                     if isinstance(c, _RtdeConnection) and c.started and c.outputs is not None]
            if not conns and self.latency <= 0:  # nobody reads: skip the outputs
                self._history.clear()
                return
            self._history.append((now, self._Snapshot(now)))
            while len(self._history) > 1 and self._history[1][0] <= now - self.latency:
                self._history.popleft()
            delayed = self._history[0][1]
        for c in conns:
            c.tick_phase += 1
            if c.tick_phase < c.outputs.period_ticks:
                continue
            c.tick_phase = 0
            if self._history and self._history[0][0] > now - self.latency:
                continue  # nothing old enough yet
            self._SendData(c, delayed)

    def _SendData(self, c: _RtdeConnection, snap: dict) -> None:
        rec = c.outputs
        flat: list = []
        for name in rec.names:
            v = snap.get(name)
            if v is None:
                v = _Zero(OUTPUT_TYPES[name])
            if isinstance(v, tuple):
                flat.extend(v)
            else:
                flat.append(v)
        try:
            payload = struct.pack(">B", rec.recipe_id) + rec.fmt.pack(*flat)
        except struct.error as err:
            LOG.error("UR emulator: cannot pack outputs %s: %s", rec.names, err)
            return
        if c.SendPackage(RTDE_DATA_PACKAGE, payload):
            self.stats["packages_sent"] += 1

    # ---- RTDE server ---------------------------------------------------------
    def _Register(self, conn: _Connection) -> bool:
        """Tracks a new client; False (and closed) while connections are
        refused after ``DropConnections``."""
        with self._lock:
            if time.monotonic() < self._refuse_until:
                LOG.debug("refused a %s connection (dropped-connection fault)", conn.kind)
                conn.Close()
                return False
            self._connections.add(conn)
            return True

    def _Unregister(self, conn: _Connection) -> None:
        conn.Close()
        with self._lock:
            self._connections.discard(conn)
            for name, owner in list(self._input_owner.items()):
                if owner is conn:
                    del self._input_owner[name]

    def _ServeRtde(self, sock: socket.socket) -> None:
        conn = _RtdeConnection(sock, self)
        if not self._Register(conn):
            return
        try:
            while not conn.closed:
                header = conn.RecvExact(3)
                if header is None:
                    break
                size, ptype = struct.unpack(">HB", header)
                payload = conn.RecvExact(size - 3) if size > 3 else b""
                if payload is None:
                    break
                self._HandleRtde(conn, ptype, payload)
        finally:
            LOG.debug("RTDE: connection closed")
            self._Unregister(conn)

    def _HandleRtde(self, conn: _RtdeConnection, ptype: int, payload: bytes) -> None:
        if ptype == RTDE_REQUEST_PROTOCOL_VERSION:
            (version,) = struct.unpack(">H", payload[:2])
            accepted = version == 2
            if accepted:
                conn.protocol_version = 2
            LOG.debug("RTDE: protocol version %d %s", version,
                      "accepted" if accepted else "refused")
            conn.SendPackage(ptype, struct.pack(">B", int(accepted)))
        elif ptype == RTDE_GET_URCONTROL_VERSION:
            conn.SendPackage(ptype, struct.pack(">IIII", *self.controller_version))
        elif ptype == RTDE_CONTROL_PACKAGE_SETUP_OUTPUTS:
            (freq,) = struct.unpack(">d", payload[:8])
            names = [n for n in payload[8:].decode().split(",") if n]
            types = [OUTPUT_TYPES.get(n, "NOT_FOUND") for n in names]
            ok = "NOT_FOUND" not in types and 0 < freq <= self.frequency + 1e-9
            rid = 0
            if ok:
                rid = conn.next_output_id
                conn.next_output_id += 1
                fmt = struct.Struct(">" + "".join(_TYPE_FORMATS[t] for t in types))
                period = max(1, int(round(self.frequency / freq)))
                conn.outputs = _OutputRecipe(rid, names, fmt, period)
            else:
                LOG.warning("RTDE: output recipe refused (frequency %.1f Hz, max %.0f; "
                            "unknown: %s)", freq, self.frequency,
                            [n for n, t in zip(names, types) if t == "NOT_FOUND"])
            LOG.debug("RTDE: output recipe %d at %.0f Hz: %s", rid, freq, ",".join(names))
            conn.SendPackage(ptype, struct.pack(">B", rid) + ",".join(types).encode())
        elif ptype == RTDE_CONTROL_PACKAGE_SETUP_INPUTS:
            names = [n for n in payload.decode().split(",") if n]
            with self._lock:
                types = []
                for n in names:
                    owner = self._input_owner.get(n)
                    if n not in INPUT_TYPES:
                        types.append("NOT_FOUND")
                    elif owner is not None and owner is not conn:
                        types.append("IN_USE")
                    else:
                        types.append(INPUT_TYPES[n])
                ok = all(t in _TYPE_FORMATS for t in types)
                rid = 0
                if ok:
                    rid = conn.next_input_id
                    conn.next_input_id += 1
                    conn.inputs[rid] = (names, struct.Struct(
                        ">" + "".join(_TYPE_FORMATS[t] for t in types)))
                    for n in names:
                        self._input_owner[n] = conn
            if not ok:
                LOG.warning("RTDE: input recipe refused: %s",
                            [f"{n}:{t}" for n, t in zip(names, types)
                             if t not in _TYPE_FORMATS])
            LOG.debug("RTDE: input recipe %d: %s", rid, ",".join(names))
            conn.SendPackage(ptype, struct.pack(">B", rid) + ",".join(types).encode())
        elif ptype == RTDE_CONTROL_PACKAGE_START:
            conn.started = conn.outputs is not None or bool(conn.inputs)
            LOG.debug("RTDE: start (%s)", "accepted" if conn.started else "refused")
            conn.SendPackage(ptype, struct.pack(">B", int(conn.started)))
        elif ptype == RTDE_CONTROL_PACKAGE_PAUSE:
            LOG.debug("RTDE: pause")
            conn.started = False
            conn.SendPackage(ptype, struct.pack(">B", 1))
        elif ptype == RTDE_DATA_PACKAGE:
            self._ReceiveInputs(conn, payload)
        elif ptype == RTDE_TEXT_MESSAGE:
            LOG.debug("RTDE: text message from client: %r", payload)
        else:
            LOG.warning("RTDE: unknown package type %r ignored", chr(ptype))

    def _ReceiveInputs(self, conn: _RtdeConnection, payload: bytes) -> None:
        rid = payload[0]
        recipe = conn.inputs.get(rid)
        if recipe is None:
            LOG.warning("RTDE: data package for unknown input recipe %d ignored", rid)
            return
        names, fmt = recipe
        flat = list(fmt.unpack(payload[1:1 + fmt.size]))
        updates, k = [], 0
        for n in names:
            size = _TYPE_SIZES[INPUT_TYPES[n]]
            updates.append((n, flat[k] if size == 1 else tuple(flat[k:k + size])))
            k += size
        self.stats["packages_received"] += 1
        with self._lock:
            t_apply = time.monotonic() + self.latency
            if self.latency <= 0 and not self._pending_inputs:
                for n, v in updates:
                    if n in self.registers:
                        self.registers[n] = v
                    else:
                        self.values[n] = v
            else:
                self._pending_inputs.append((t_apply, updates))

    # ---- script port ---------------------------------------------------------
    def _ServeScript(self, sock: socket.socket) -> None:
        conn = _Connection(sock, "script")
        if not self._Register(conn):
            return
        buf = ""
        try:
            while not conn.closed:
                try:
                    data = sock.recv(65536)
                except OSError:
                    break
                if not data:
                    break
                buf += data.decode(errors="replace")
                buf = self._ParsePrograms(buf)
        finally:
            self._Unregister(conn)

    def _ParsePrograms(self, buf: str) -> str:
        """Runs every complete program in ``buf``; returns the rest. A program
        is ``def``/``sec`` ... a line ``end`` at column 0; other complete
        lines are one-line programs."""
        while True:
            lines = buf.split("\n")
            if len(lines) < 2:
                return buf
            first = lines[0]
            if not first.strip():
                buf = "\n".join(lines[1:])
                continue
            if re.match(r"(def|sec)\s+\w+\s*\(", first):
                end = next((i for i, ln in enumerate(lines[:-1]) if i > 0 and ln.rstrip() == "end"),
                           None)
                if end is None:
                    return buf
                self._RunProgram("\n".join(lines[:end + 1]))
                buf = "\n".join(lines[end + 1:])
            else:
                self._RunProgram(first)
                buf = "\n".join(lines[1:])

    def _RunProgram(self, program: str) -> None:
        self.programs.append(program)
        LOG.debug("script port: program received:\n%s", program)
        head = program.strip().splitlines()[0] if program.strip() else ""
        with self._lock:
            if self.script is not None and self.script.running:
                self.script.Terminate("control script replaced by a new program")
            if "rtde_cmd()" in program and "process_cmd" in program:
                if self.protective_stopped or self.emergency_stopped or not self.powered:
                    LOG.warning("script port: control script refused (robot %s)",
                                "protective stopped" if self.protective_stopped
                                else "emergency stopped / powered off")
                    return
                try:
                    oi = _ScriptInt(program, "reg_offset_int")
                    of = _ScriptInt(program, "reg_offset_float")
                except ValueError as err:
                    LOG.error("script port: %s; the control script is not run", err)
                    return
                self.arm.Hold("idle")
                self.script = ControlScript(self, oi, of)
                LOG.info("script port: ur_rtde control script running (%d lines, register "
                         "offsets int %d float %d)", program.count("\n") + 1, oi, of)
            else:
                self.arm.Stop(20.0)
                LOG.warning("script port: program %r is not emulated (only ur_rtde's control "
                            "script is); the arm stops", head[:80])

    # ---- dashboard -----------------------------------------------------------
    def _ServeDashboard(self, sock: socket.socket) -> None:
        conn = _Connection(sock, "dashboard")
        if not self._Register(conn):
            return
        conn.Send(b"Connected: Universal Robots Dashboard Server\n")
        buf = b""
        try:
            while not conn.closed:
                try:
                    data = sock.recv(4096)
                except OSError:
                    break
                if not data:
                    break
                buf += data
                while b"\n" in buf:
                    line, buf = buf.split(b"\n", 1)
                    command = line.decode(errors="replace").strip()
                    if not command:
                        continue
                    reply = self._Dashboard(command)
                    if self.latency > 0:
                        time.sleep(self.latency)
                    conn.Send((reply + "\n").encode())
                    if command == "quit":
                        conn.Close()
        finally:
            self._Unregister(conn)

    def _PolyscopeVersion(self) -> str:
        major, minor, bugfix, build = self.controller_version
        return f"URSoftware {major}.{minor}.{bugfix}.{build} (Jan 01 2024)"

    def _Dashboard(self, command: str) -> str:
        """The reply of the dashboard server to one command."""
        self.dashboard_log.append(command)
        LOG.debug("dashboard: %r", command)
        c = command.lower()
        with self._lock:
            running = self.script is not None and self.script.running
            if c == "polyscopeversion":
                return self._PolyscopeVersion()
            if c == "version":
                return ".".join(str(v) for v in self.controller_version)
            if c == "get serial number":
                return self.serial_number
            if c == "get robot model":
                return self.robot_model
            if c == "robotmode":
                return f"Robotmode: {ROBOT_MODE_NAMES[self._RobotMode()]}"
            if c == "safetymode":
                return f"Safetymode: {SAFETY_MODE_NAMES[self._SafetyMode()]}"
            if c == "safetystatus":
                return f"Safetystatus: {SAFETY_MODE_NAMES[self._SafetyMode()]}"
            if c == "programstate":
                return "PLAYING rtde_control" if running else "STOPPED <unnamed>"
            if c == "running":
                return f"Program running: {'true' if running else 'false'}"
            if c == "is in remote control":
                return "true"
            if c == "get loaded program":
                return "No program loaded"
            if c == "stop":  # a real one answers "Failed to execute: stop" when idle,
                if running:  # which ur_rtde's reconnect takes as an error
                    self.arm.Stop(20.0)
                    self._StopScriptLocked("control script stopped by dashboard stop")
                return "Stopped"
            if c == "play":
                return "Failed to execute: play"  # no installed program to play
            if c == "pause":
                return "Failed to execute: pause"
            if c == "power on":
                if self.emergency_stopped:
                    return "Failed to execute: power on (emergency stopped)"
                self.powered = True
                return "Powering on"
            if c == "power off":
                self.powered = False
                self.arm.Hold("halted")
                self._StopScriptLocked("control script stopped: power off")
                return "Powering off"
            if c == "brake release":
                return "Brake releasing"
            if c == "unlock protective stop":
                self.protective_stopped = False
                return "Protective stop releasing"
            if c == "close safety popup":
                return "closing safety popup"
            if c == "close popup":
                return "closing popup"
            if c.startswith("popup"):
                return "showing popup"
            if c == "restart safety":
                self.protective_stopped = False
                return "Restarting safety"
            if c == "quit":
                return "Disconnected"
        return f"could not understand: '{command}'"


def _Zero(type_: str):
    n = _TYPE_SIZES[type_]
    zero = False if type_ == "BOOL" else (0.0 if "D" in type_ else 0)
    return zero if n == 1 else (zero,) * n


def _ScriptInt(program: str, name: str) -> int:
    """``global NAME = VALUE`` of a script; ur_rtde 1.6.5 injects the
    register offsets after the line's comment, so VALUE may start the next
    line (``= # int register offset\\n24    global ...``)."""
    m = re.search(rf"global\s+{name}\s*=\s*(?:#[^\n]*\n)?\s*(\d+)", program)
    if m is None:
        raise ValueError(f"the uploaded control script sets no {name}")
    return int(m.group(1))


# ------------------------------------------------------------------ shared state
class SharedArmState:
    """The arm's state shared by the emulator's process and a digital
    twin's (``multiprocessing.shared_memory``: no pipe round trip per
    step). The emulator writes, every controller cycle, its servo model's
    joints (rad: the command the simulated arm tracks) and its stop flags;
    the twin writes the simulated arm's measured joints (rad, rad/s) and
    wrist force (N), which the emulator then reports as ``actual_q`` /
    ``actual_qd`` and ``actual_TCP_force`` (its force part). Each side's
    block starts with a sequence counter, odd while it is being written
    (a seqlock: a reader retries a torn read). ``name=None`` creates the
    block (its owner unlinks it on ``Close``); a name attaches to it."""
    SIZE = 32                      # float64 slots
    _SERVO, _MEASURED = 0, 16      # [seq, q(6), protective, estop] / [seq, q(6), qd(6), f(3)]

    def __init__(self, name: str | None = None):
        from multiprocessing import resource_tracker, shared_memory
        self.owner = name is None
        self.shm = shared_memory.SharedMemory(name=name, create=self.owner, size=self.SIZE * 8)
        if not self.owner:         # the creator unlinks it, not this process's tracker
            resource_tracker.unregister(self.shm._name, "shared_memory")
        self.a = np.ndarray((self.SIZE,), np.float64, buffer=self.shm.buf)
        if self.owner:
            self.a[:] = 0.0

    @property
    def name(self) -> str:
        return self.shm.name

    def _Write(self, base: int, values) -> None:
        a = self.a
        a[base] += 1.0
        a[base + 1:base + 1 + len(values)] = values
        a[base] += 1.0

    def _Read(self, base: int, n: int) -> tuple[float, np.ndarray]:
        a = self.a
        for _ in range(10000):
            seq = a[base]
            if seq % 2 == 0:
                values = a[base + 1:base + 1 + n].copy()
                if a[base] == seq:
                    return seq, values
            time.sleep(0)
        raise RuntimeError("shared arm state: no consistent read")

    def WriteServo(self, q, protective_stopped: bool, emergency_stopped: bool) -> None:
        self._Write(self._SERVO, [*q, float(protective_stopped), float(emergency_stopped)])

    def ReadServo(self) -> tuple[np.ndarray, bool, bool] | None:
        """(servo joints, protective stop, emergency stop); None before the
        emulator's first cycle."""
        seq, v = self._Read(self._SERVO, 8)
        return None if seq == 0 else (v[:6], bool(v[6]), bool(v[7]))

    def WriteMeasured(self, q, qd, tcp_force=(0.0, 0.0, 0.0)) -> None:
        self._Write(self._MEASURED, [*q, *qd, *tcp_force])

    def ReadMeasured(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """(q rad, qd rad/s, the wrist force N) the twin wrote last."""
        seq, v = self._Read(self._MEASURED, 15)
        return None if seq == 0 else (v[:6], v[6:12], v[12:15])

    def Close(self) -> None:
        self.a = None
        self.shm.close()
        if self.owner:
            try:
                self.shm.unlink()
            except FileNotFoundError:
                pass


# ------------------------------------------------------------------ control
def EmulatorState(emu: UrEmulator) -> dict:
    """JSON-ready view of the emulator (arm, faults, script, statistics)."""
    with emu._lock:
        script = emu.script
        return {
            "host": emu.host, "ports": emu.ports, "frequency": emu.frequency,
            "q_actual": emu.actual[0].tolist(), "qd_actual": emu.actual[1].tolist(),
            "q_servo": emu.arm.q.tolist(), "measured": emu._measured is not None,
            "q_command": emu.arm.q_ref.tolist(), "motion": emu.arm.motion.kind,
            "tcp_pose": TransformToPose(TcpTransform(emu.actual[0], emu.arm.tcp_offset)).tolist(),
            "script_running": bool(script is not None and script.running),
            "commands_seen": {CMD_NAMES.get(k, str(k)): v
                              for k, v in (script.commands_seen.items() if script else [])},
            "protective_stopped": emu.protective_stopped,
            "emergency_stopped": emu.emergency_stopped, "powered": emu.powered,
            "latency": emu.latency, "stats": dict(emu.stats), "fault_log": list(emu.fault_log),
            "dashboard_log": emu.dashboard_log[-50:], "programs": len(emu.programs),
            "connections": sorted(c.kind for c in emu._connections),
        }


def ControlCommand(emu: UrEmulator, line: str) -> dict:
    """Runs one line of the control protocol (``--control-stdin``):
    ``state``, ``protective_stop``, ``unlock_protective_stop``, ``estop``,
    ``release_estop``, ``drop [REFUSE_S]``, ``latency S``, ``set_actual q1 .. q6``.
    Returns ``{"ok": bool, ...state or error}``."""
    words = line.split()
    if not words:
        return {"ok": False, "error": "empty command"}
    cmd, args = words[0], words[1:]
    try:
        if cmd == "protective_stop":
            emu.ProtectiveStop("control command")
        elif cmd == "unlock_protective_stop":
            emu.UnlockProtectiveStop()
        elif cmd == "estop":
            emu.EmergencyStop("control command")
        elif cmd == "release_estop":
            emu.ReleaseEmergencyStop()
        elif cmd == "drop":
            emu.DropConnections("control command", float(args[0]) if args else 0.0)
        elif cmd == "latency":
            emu.SetLatency(float(args[0]))
        elif cmd == "set_actual":
            if len(args) != 6:
                raise ValueError("set_actual needs 6 joint positions")
            emu.SetActual([float(a) for a in args])
        elif cmd != "state":
            raise ValueError(f"unknown control command {cmd!r}")
    except (ValueError, IndexError) as err:
        return {"ok": False, "error": str(err)}
    return {"ok": True, **EmulatorState(emu)}


class EmulatorProcess:
    """A ``UrEmulator`` in a child Python process, driven over its stdin.

    ur_rtde's Python bindings keep the GIL while they wait for the
    controller (the constructors, moveJ, ...), so the emulator cannot answer
    a ur_rtde client that runs in its own process: tests and tools start it
    here. The child exits when this object is closed or its stdin closes.
    Raises ``OSError`` (with the emulator's log) when it cannot start, e.g.
    a port in use."""

    def __init__(self, host: str = "127.0.0.1", *, latency: float = 0.0, cb3: bool = False,
                 q0=None, verbose: bool = False, log_path: str | None = None,
                 startup_timeout: float = 30.0, shared_state: bool = False,
                 allow_remote: bool = False):
        ListenHostWarning(host, allow_remote)    # ListenError before any child or file
        self.host = host
        # the arm's state in shared memory (a twin's): ``shared`` reads and writes it
        self.shared = SharedArmState() if shared_state else None
        self._own_log = log_path is None  # a temporary log, removed by Close
        if log_path is None:
            fd, log_path = tempfile.mkstemp(prefix="ur_emulator_", suffix=".log")
            os.close(fd)
        self.log_path = log_path
        cmd = [sys.executable, "-m", "lmap_drake.twin.ur_emulator", "--host", host,
               "--latency", str(latency), "--control-stdin"]
        if cb3:
            cmd.append("--cb3")
        if allow_remote:
            cmd.append("--allow_remote")
        if q0 is not None:
            cmd += ["--q0", *[repr(float(v)) for v in q0]]
        if verbose:
            cmd.append("--verbose")
        if self.shared is not None:
            cmd += ["--shared-state", self.shared.name]
        self._log = open(log_path, "w")
        self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=self._log, text=True, bufsize=1)
        self._lock = threading.Lock()
        self._lines: collections.deque = collections.deque()  # stdout lines, None at EOF
        self._cond = threading.Condition()
        threading.Thread(target=self._Read, daemon=True, name="ur_emu_proc_reader").start()
        ready = self._NextLine(startup_timeout)
        if ready is None or not ready.startswith("{"):
            try:
                self.proc.wait(timeout=1.0)  # a failing child exits after its message
            except subprocess.TimeoutExpired:
                pass
            tail = self.LogTail()
            self.Close()
            raise OSError(f"the UR emulator on {host} did not start: {tail}")
        self.info = json.loads(ready)

    def _Read(self) -> None:
        for line in self.proc.stdout:
            with self._cond:
                self._lines.append(line.strip())
                self._cond.notify_all()
        with self._cond:
            self._lines.append(None)
            self._cond.notify_all()

    def _NextLine(self, timeout: float) -> str | None:
        with self._cond:
            if not self._cond.wait_for(lambda: self._lines, timeout):
                return None
            return self._lines.popleft()

    def LogTail(self, n: int = 20) -> str:
        try:
            with open(self.log_path) as f:
                return " | ".join(f.read().strip().splitlines()[-n:]) or "(empty log)"
        except OSError:
            return "(no log)"

    def Command(self, line: str, timeout: float = 10.0) -> dict:
        """Sends one control command; returns the reply (raises on error)."""
        with self._lock:
            if self.proc.poll() is not None:
                raise RuntimeError(f"the UR emulator exited ({self.proc.returncode}): "
                                   f"{self.LogTail()}")
            self.proc.stdin.write(line + "\n")
            self.proc.stdin.flush()
            reply = self._NextLine(timeout)
        if reply is None:
            raise RuntimeError(f"the UR emulator did not answer {line!r}: {self.LogTail()}")
        out = json.loads(reply)
        if not out.get("ok"):
            raise ValueError(f"UR emulator: {out.get('error')}")
        return out

    def State(self) -> dict:
        return self.Command("state")

    def ProtectiveStop(self) -> dict:
        return self.Command("protective_stop")

    def UnlockProtectiveStop(self) -> dict:
        return self.Command("unlock_protective_stop")

    def EmergencyStop(self) -> dict:
        return self.Command("estop")

    def ReleaseEmergencyStop(self) -> dict:
        return self.Command("release_estop")

    def DropConnections(self, refuse_s: float = 0.0) -> dict:
        return self.Command(f"drop {float(refuse_s)!r}")

    def SetLatency(self, seconds: float) -> dict:
        return self.Command(f"latency {float(seconds)!r}")

    def Close(self) -> None:
        """Stops the child (idempotent); removes a temporary log."""
        if self.proc.poll() is None:
            try:
                self.proc.stdin.close()
                self.proc.wait(timeout=3.0)
            except Exception:
                self.proc.kill()
                self.proc.wait()
        self._log.close()
        if self._own_log:
            try:
                os.remove(self.log_path)
            except OSError:
                pass
        if self.shared is not None:
            self.shared.Close()
            self.shared = None

    def __enter__(self) -> "EmulatorProcess":
        return self

    def __exit__(self, *exc) -> None:
        self.Close()


# ------------------------------------------------------------------ CLI
def main(argv=None) -> int:
    """``python -m lmap_drake.twin.ur_emulator``: serves until
    Ctrl-C (or, with ``--control-stdin``, until stdin closes)."""
    p = argparse.ArgumentParser(
        prog="python -m lmap_drake.twin.ur_emulator",
        description="Loopback EMULATOR of a UR controller (dashboard, RTDE, script port) for "
                    "ur_rtde; not a robot. Connect with rtde_control.RTDEControlInterface(HOST) "
                    "and rtde_receive.RTDEReceiveInterface(HOST) from another process.")
    p.add_argument("--host", default="127.0.0.1",
                   help="loopback address to bind (127.x.y.z; another one needs --allow_remote)")
    p.add_argument("--allow_remote", action="store_true",
                   help="allow a --host that is not loopback (the ports control the emulated "
                        "arm without authentication; a warning is printed)")
    p.add_argument("--dashboard-port", type=int, default=DASHBOARD_PORT)
    p.add_argument("--rtde-port", type=int, default=RTDE_PORT)
    p.add_argument("--script-port", type=int, default=SCRIPT_PORT)
    p.add_argument("--cb3", action="store_true",
                   help=f"report a CB3 controller {CB3_VERSION[:3]} (125 Hz) instead of an "
                        f"e-Series {E_SERIES_VERSION[:3]} (500 Hz)")
    p.add_argument("--q0", type=float, nargs=6, default=list(Q_HOME), metavar="Q",
                   help="initial joint positions (rad)")
    p.add_argument("--latency", type=float, default=0.0, help="added latency (s) both ways")
    p.add_argument("--protective-stop-after", type=float, metavar="S",
                   help="inject a protective stop S seconds after the control script starts")
    p.add_argument("--estop-after", type=float, metavar="S",
                   help="inject an emergency stop S seconds after the control script starts")
    p.add_argument("--drop-after", type=float, metavar="S",
                   help="drop every connection S seconds after the control script starts")
    p.add_argument("--control-stdin", action="store_true",
                   help="machine mode: print one JSON line when ready, then answer control "
                        "commands read from stdin (state, protective_stop, "
                        "unlock_protective_stop, estop, release_estop, drop [REFUSE_S], latency S, "
                        "set_actual q1..q6) with one JSON line each; exit at end of stdin")
    p.add_argument("--shared-state", metavar="NAME",
                   help="exchange the arm's state with a digital twin through this shared "
                        "memory block (SharedArmState): report its measured joints as "
                        "actual_q")
    p.add_argument("--verbose", "-v", action="store_true", help="log every protocol exchange")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(levelname)s %(message)s")
    for option in ("latency", "protective_stop_after", "estop_after", "drop_after"):
        value = getattr(args, option)
        if value is not None and not (math.isfinite(value) and value >= 0):
            p.error(f"--{option.replace('_', '-')} must be a finite number >= 0, got {value}")
    try:
        for option in ("dashboard_port", "rtde_port", "script_port"):
            CheckPort(getattr(args, option), f"--{option.replace('_', '-')}")
        warning = ListenHostWarning(args.host, args.allow_remote)
    except ListenError as err:
        p.error(str(err))
    if warning:
        print(warning, file=sys.stderr, flush=True)
    emu = UrEmulator(args.host, args.q0, dashboard_port=args.dashboard_port,
                     rtde_port=args.rtde_port, script_port=args.script_port,
                     controller_version=CB3_VERSION if args.cb3 else E_SERIES_VERSION,
                     latency=args.latency, allow_remote=args.allow_remote)
    try:
        if args.shared_state:
            emu.AttachSharedState(args.shared_state)
        emu.Start()
    except OSError as err:
        print(f"error: {err.strerror}", file=sys.stderr, flush=True)
        return 1
    if args.control_stdin:
        print(json.dumps(EmulatorState(emu)), flush=True)
        try:
            for line in sys.stdin:
                if line.strip():
                    print(json.dumps(ControlCommand(emu, line)), flush=True)
        except KeyboardInterrupt:
            pass
        finally:
            emu.Close()
        return 0
    signal.signal(signal.SIGTERM, signal.default_int_handler)  # kill: stop like Ctrl-C
    print(f"UR controller EMULATOR (not a robot) on {args.host}: dashboard "
          f"{emu.ports['dashboard']}, RTDE {emu.ports['rtde']}, script {emu.ports['script']}, "
          f"{emu.frequency:.0f} Hz, latency {emu.latency:.3f} s. Ctrl-C stops it.", flush=True)
    faults = [(args.protective_stop_after, emu.ProtectiveStop),
              (args.estop_after, emu.EmergencyStop), (args.drop_after, emu.DropConnections)]
    faults = [(t, f) for t, f in faults if t is not None]
    t_script = None
    try:
        while True:
            time.sleep(0.01)
            if t_script is None and emu.script_running:
                t_script = time.monotonic()
            for t, inject in list(faults):
                if t_script is not None and time.monotonic() - t_script >= t:
                    inject(f"{inject.__name__} {t} s after the control script started")
                    print(f"injected: {emu.fault_log[-1]}", flush=True)
                    faults.remove((t, inject))
    except KeyboardInterrupt:
        print("stopping the UR emulator", flush=True)
    finally:
        emu.Close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
