"""The force guard of the episode's state machine (``arm_sequence``): the
station's wrist force (``ur5.wrist_force``, N) watched while a held leaf
moves (``planner.max_pull_force``) and while the open gripper backs out of
the plant after the release (``planner.max_retreat_force``). Why the limits
have their values: docs/explanation/planner-parameters.md, "The force
guard stops what the model did not predict".

The functions act on the ``ControllerStatus`` ``st`` through the
``ArmSequence`` ``seq`` (its planner config, motions, mode changes) and
the ``ArmInputs`` ``inputs``; each returns whether it changed the mode.
"""
from __future__ import annotations

from itertools import islice

import numpy as np
from pydrake.trajectories import PiecewisePolynomial

# The pull's zero is read at the pre-grasp pose once every joint is slower
# than this (rad/s), or MAX_SETTLE_TIME (s) after the move there ended: as
# a fast move ends the tool's own inertia still reads several newtons
# (12.6 N in the default scene).
SETTLED_JOINT_SPEED = 0.01
MAX_SETTLE_TIME = 1.0

# The retreat guard acts on the median of the last RETREAT_WINDOW rises
# (samples of the controller, 20 ms apart): a leaf caught on the gripper
# loads it for as long as the arm backs out, while the tool's own inertia
# reads as one-sample spikes when the arm's commands arrive in bursts. On
# the digital twin on a loaded 2-core machine the way out of the default
# scene read 2-4 N, then one sample of 8.2-16.7 N (the last before the
# stop; the same with the pads opened to the approach's 3.5 cm), in 3 of 3
# runs with the test suite or two busy processes beside it, and passed
# alone. A rise that lasts stops the arm two samples (40 ms, 4 mm at the
# approach's 10 cm/s) later than before. (The bursts were the twin's own
# held servo samples; it now ramps between them: 0.5-0.6 N median, peak
# 3.9-5.9 N: docs/explanation/planner-parameters.md.)
RETREAT_WINDOW = 5

# A stop eases the commanded joints to rest over STOP_TIME (s) from where
# the command stands, at its speed: a command that jumped back to the
# measured joints (behind the command by the servo's lag) read as a
# one-step backward velocity in the station's desired state and jerked
# the held leaf. gh_random_7575_002 (default segmenter): the pull guard
# stopped an arc at 8.5 N with the petiole at 11.0 N and the blade strain
# at 1.08; the jerk's one sample read 19.5 N and 1.16 (limits 15 N, 1.10),
# then both settled at 11.8 N and 1.09. Two controller steps (20 ms
# each): the shortest ease the command can follow; the leaf is taut when
# the guard acts, and every mm further counts (eased over 0.1 s, 2 mm
# further, that stop read 14.9 N and 1.12; over 0.04 s, 13.2 N and 1.10).
STOP_TIME = 0.04


def EaseToRest(trajectory, t: float, duration: float = STOP_TIME):
    """(A trajectory from the command at ``t`` of ``trajectory`` (joint
    positions rad, velocities rad/s) to rest ``duration`` s later, cubic,
    the velocity falling to 0; where it ends, rad). The joints travel half
    the command's speed times ``duration`` further."""
    q = np.asarray(trajectory.value(t), float).ravel()
    v = (np.asarray(trajectory.EvalDerivative(t, 1), float).ravel()
         if t < trajectory.end_time() else np.zeros_like(q))
    q_end = q + 0.5 * duration * v
    ease = PiecewisePolynomial.CubicHermite([t, t + duration], np.c_[q, q_end],
                                            np.c_[v, np.zeros_like(v)])
    return ease, q_end


def ExecutedPart(path: list, q_now: np.ndarray) -> list:
    """The part of joint ``path`` (waypoints from its start) executed up to
    ``q_now`` (a configuration on it): the waypoints up to the one nearest
    ``q_now`` (that one too when ``q_now`` lies past it, nearer the next
    than it is), then ``q_now``."""
    q_now = np.asarray(q_now, float)
    if not path:
        return [q_now]
    P = [np.asarray(q, float) for q in path]
    k = int(np.argmin([np.linalg.norm(q - q_now) for q in P]))
    passed = k + 1 < len(P) and (np.linalg.norm(q_now - P[k + 1])
                                 <= np.linalg.norm(P[k] - P[k + 1]))
    return P[:k + 1 if passed else k] + [q_now]


def ExecutedFraction(planned: list, executed: list) -> float:
    """The executed part's share of a planned joint path (lengths in joint
    space, rad), in [0, 1]: how much of the motion is carried back."""
    def length(path):
        P = np.asarray(path, float).reshape(len(path), -1)
        return float(np.linalg.norm(np.diff(P, axis=0), axis=1).sum()) if len(P) > 1 else 0.0
    total = length(planned)
    return 1.0 if total <= 0.0 else float(np.clip(length(executed) / total, 0.0, 1.0))


def ZeroAtPregrasp(inputs, st, t: float) -> bool:
    """At the pre-grasp pose, before the open gripper reaches into the
    plant: the pull's zero (``st.force_zero``), read once the arm has
    settled (a grasp that already presses the leaf, or a neighbour, then
    counts against the limit). False while it waits for the arm."""
    f = inputs.wrist_force()
    if f is None:
        return True
    settling = t - st.trajectory.end_time() if st.trajectory is not None else np.inf
    moving = float(np.abs(inputs.measured_state()[6:]).max()) > SETTLED_JOINT_SPEED
    if moving and settling < MAX_SETTLE_TIME:
        return False
    st.force_zero = np.asarray(f, float).copy()
    return True


def _Rise(st, f, zero: np.ndarray, t: float, phase: str) -> float:
    """The wrist force's rise above ``zero`` (N), logged in the trace."""
    rise = float(np.linalg.norm(np.asarray(f, float) - zero))
    st.force_trace.append((round(t, 3), round(rise, 3), phase))
    return rise


def _RecordStop(st, t: float, rise: float, motion) -> None:
    """One stop of the guard in ``st.force_stops``."""
    st.force_stops = st.force_stops + [{"t": round(t, 3), "rise_N": round(rise, 2),
                                        "motion": motion, "target": len(st.targets)}]


def PullGuard(seq, inputs, st, t: float) -> bool:
    """``planner.max_pull_force``: True when the wrist force has risen more
    than the limit above ``st.force_zero``; the arm then comes to rest
    (``EaseToRest``: a few mm further along), the executed part becomes the
    motion's path (what is carried back), and the mode is ``hold`` (then
    observe, no further motion, release)."""
    limit = float(seq._planner.max_pull_force)
    if st.force_zero is None or st.trajectory is None:
        return False
    f = inputs.wrist_force()
    if f is None:
        return False
    rise = _Rise(st, f, st.force_zero, t, "pull")
    st.force_peak = max(st.force_peak, rise)
    if limit <= 0.0 or rise <= limit:
        return False
    st.trajectory, q_end = EaseToRest(st.trajectory, t)
    st.motion_paths = st.motion_paths[:-1] + [ExecutedPart(st.motion_paths[-1], q_end)]
    st.q_hold = q_end
    st.force_stop = (f"force guard: the wrist force rose {rise:.1f} N above its value "
                     f"before the grasp (planner.max_pull_force {limit:g} N); the motion "
                     "stopped there")
    _RecordStop(st, t, rise, len(st.motion_paths))
    seq._enter(st, "hold", t, st.force_stop)
    return True


def RetreatGuard(seq, inputs, st, t: float) -> bool:
    """``planner.max_retreat_force`` on the way out of the plant (grasp ->
    pre-grasp, the open gripper backing out): a leaf the gripper's body or
    pads drag (one sprung back around them while the leaf was held) loads
    its petiole as the arm backs out. When the wrist force rises more than
    the limit above ``st.retreat_zero`` (read at rest before the retreat,
    or at its first step), the arm goes back (``back_off``) to where it let
    the leaf go, which unloads the dragged leaf. True when it stopped."""
    limit = float(seq._planner.max_retreat_force)
    f = inputs.wrist_force()
    if f is None or limit <= 0.0 or st.trajectory is None:
        return False
    f = np.asarray(f, float)
    if st.retreat_zero is None:
        st.retreat_zero = f.copy()
        return False
    rise = _Rise(st, f, st.retreat_zero, t, "retreat")
    st.retreat_peak = max(st.retreat_peak, rise)
    # (from the end: the trace holds the whole episode)
    recent = islice((r for _, r, phase in reversed(st.force_trace) if phase == "retreat"),
                    RETREAT_WINDOW)
    rise = float(np.median(list(recent)))
    if rise <= limit:
        return False
    q_now = np.asarray(inputs.measured_state()[:6], float).copy()
    back = ExecutedPart(st.retreat_out, q_now)[:-1][::-1] or [st.retreat_out[0]]
    st.trajectory = None
    st.q_hold = q_now
    seq._start_path(st, t, back, **seq.motions.ApproachTiming(q_now, back,
                                                              seq.motions.pull_speed))
    st.segments, st.retreat_out, st.retreat_zero = [], [], None
    why = (f"force guard: backing out of the plant, the wrist force rose {rise:.1f} N "
           f"(planner.max_retreat_force {limit:g} N): a leaf is caught on the gripper")
    _RecordStop(st, t, rise, "retreat")
    seq._enter(st, "back_off", t, why + "; going back to where the leaf was released")
    return True


def BackOffDone(seq, st, t: float) -> None:
    """The arm is back where it released the leaf (or, after a missed
    grasp, where the pads closed on nothing): the target's record closes
    (several fruits) and the episode aborts there, gripper open."""
    st.trajectory = None
    why = st.message.split("; going back")[0]
    if seq._multi:
        seq._EndTarget(st, t, (st.grasp_missed + "; then " if st.grasp_missed
                               else "revealed, then ") + "the retreat was stopped: " + why)
    st.grasp_missed = ""
    seq._enter(st, "aborted", t, why + "; the arm went back to where the leaf was released "
               "and stopped there, gripper open: free the leaf, then move the arm out")
