"""The episode's state machine (paper Sec. III-D) without a Diagram: the
same on the simulated and the hardware station; ``ArmController`` steps it
on its periodic update, with its input ports as ``ArmInputs``.

    idle -> capture -> plan_requested [-> confirm_wait] -> pregrasp ->
    approach -> close_gripper -> grasp_wait -> pull -> hold -> observe
    [-> [confirm_wait ->] pull -> hold -> observe, up to planner.max_replans]
    -> release -> retreat -> done            (or planned, or aborted)
                      [-> back_off -> aborted: the force guard stopped the retreat]

With ``planner.targets: all`` (several fruits) the plan is
``PlantPlanning``'s plan for the next fruit; after ``retreat`` the fruit's
record joins ``status.targets`` and the controller captures a new view and
plans again (a fruit without a feasible action is recorded and skipped),
until the plan says no action is needed (every fruit visible or handled).

``pull`` executes the chosen motion, a straight pull or a hinge arc
(``planning.motion.PlanActionPath``). After ``observe`` (re-estimation on the
fused views) the continuation (``ContinuationPlanning``: a further motion
from the held leaf, planned on the newest view) is evaluated while re-plans
are left; when it has an action, that motion runs from the held pose (after
the operator's yes with ``confirm``; a no releases the leaf). Release: the
arm carries the held leaf back along every executed motion to where it was
grasped, then the gripper opens ``planner.release_opening`` past the
leaf (no spring-back) and the way out waits for the pads (``PadsOpened``,
at most 2 s); retreat: the approach in
reverse (grasp -> pre-grasp -> ready -> via), then the start pose. The
status, its modes and the options are in ``arm_status``; the joint paths
and their timing in ``arm_motion``.

The force guard (``planner.max_pull_force``, the station's wrist force):
a held leaf's motion that loads the wrist past the limit stops there (then
hold, observe, no further motion, release); a retreat that does, on its way
out of the plant, goes back to where the leaf was released and aborts.

The episode aborts cleanly (holds the measured position and leaves the
gripper as it is: a held leaf is never dropped by surprise; ``aborted``
with a message) when the planner finds no feasible action, the fruit is not
seen, IK fails, a trajectory is refused, or a stage raises (``stage_error:
<stage>: ...``, ``failed_stage``); it skips the manipulation (``done``,
``no_action_needed``) when the fruit is already visible enough. In
simulation the grasp is made by the episode runner (it rebuilds the station
with the leaf fixed between the pads, see ``lmap_drake.plants.plant_sim``),
which then acknowledges it; on hardware the gripper closes until it stalls
on the leaf and the controller continues alone. A hardware gripper that
reaches the end of its ramp (or 2 s) without reporting an object holds
nothing: it opens, the arm retreats and the target ends ``grasp missed``
(``aborted`` for a single fruit; the next fruit of a plant).
"""
from __future__ import annotations

import time
from typing import Protocol

import numpy as np

from lmap_drake.planning.result import PlanResult
from lmap_drake.planning.motion import MotionError
from lmap_drake.planning.robot_model import RobotModel
from lmap_drake.systems.arm_guard import (BackOffDone, ExecutedFraction, PullGuard,
                                          RetreatGuard, ZeroAtPregrasp)
from lmap_drake.systems.arm_motion import ArmMotions, Refused
from lmap_drake.systems.arm_status import (STALL_WINDOW, ControllerOptions, ControllerStatus,
                                           GripperCommand, PadsOpened, ReleaseOpening)
from lmap_drake.types import SceneEstimate


class ArmInputs(Protocol):
    """What the state machine reads, evaluated only when asked (each pulls
    its part of the Diagram): the planning stages, the re-estimation, the
    continuation, and the station's measurements."""

    def semantic_scene(self): ...                  # Perception, to time it
    def scene_estimate(self) -> SceneEstimate: ...  # ShapeCompletion, view 0
    def plan(self) -> PlanResult: ...
    def final_estimate(self) -> SceneEstimate: ...  # re-estimation on the fused views
    def has_continuation(self) -> bool: ...         # (evaluates it when connected)
    def continuation(self) -> PlanResult: ...
    def views_fused(self) -> int: ...               # a large number when not connected
    def gripper_state(self) -> np.ndarray: ...      # (opening m, rate m/s, object flag)
    def measured_state(self) -> np.ndarray: ...     # (12,): q rad, v rad/s
    def wrist_force(self) -> np.ndarray | None: ...  # (3,) N, or None without a sensor


class StageFailure(Exception):
    """A stage (Perception, ShapeCompletion, a planner stage) raised."""

    def __init__(self, stage: str, error: Exception):
        super().__init__(stage)
        self.stage, self.error = stage, error


def _Stage(stage: str, evaluate):
    """``evaluate()``; an exception becomes a StageFailure naming the stage
    (Perception, ShapeCompletion, the planner stages)."""
    try:
        return evaluate()
    except MotionError:
        raise
    except Exception as err:  # noqa: BLE001
        raise StageFailure(stage, err) from err


class ArmSequence:
    """Steps a ``ControllerStatus`` (see the module docstring). ``planner``
    is the scenario's planner section; ``q_start`` the joints the episode
    returns to; ``settle`` (s) before the first capture, ``hold`` (s) after
    each motion before observing; ``progress(message)`` hears every mode."""

    def __init__(self, planner, robot: RobotModel, options: ControllerOptions,
                 q_start: np.ndarray, settle: float = 0.3, hold: float = 0.5,
                 pull_speed: float = 0.03, progress=None):
        self._planner = planner
        self._options = options
        self._q_start = q_start
        self._settle, self._hold = settle, hold
        self._release_time = 0.5
        self._speed_scale = float(planner.speed_scale)
        self._pregrasp_opening = planner.pregrasp_opening
        self._max_replans = int(planner.max_replans)
        self._multi = planner.targets == "all"
        self.motions = ArmMotions(planner, robot, pull_speed, options.max_joint_speed,
                                  options.trajectory_check)
        self.progress = progress or (lambda msg: None)
        self._modes = {
            "idle": self._Idle, "capture": self._Capture, "plan_requested": self._Plan,
            "confirm_wait": self._ConfirmWait, "pregrasp": self._Pregrasp,
            "approach": self._Approach, "close_gripper": self._CloseGripper,
            "grasp_wait": self._GraspWait, "pull": self._Pull, "hold": self._Hold,
            "observe": self._Observe, "release": self._Release, "retreat": self._Retreat,
            "back_off": self._BackOff}

    def Update(self, inputs: ArmInputs, st: ControllerStatus, t: float) -> None:
        """One step of the mode in ``st`` (modified in place). Never raises:
        a failure aborts (the arm holds, the gripper keeps its command)."""
        before = st.mode
        try:
            step = self._modes.get(st.mode)
            if step is not None:
                step(inputs, st, t)
        except MotionError as err:
            self._Stop(inputs, st, t)
            self._enter(st, "aborted", t, f"IK failure: {err}")
        except Refused as err:
            self._Stop(inputs, st, t)
            self._enter(st, "aborted", t, f"refused by the safety checks in {before}: {err}")
        except StageFailure as err:
            self._Fail(inputs, st, t, err.stage, err.error)
        except Exception as err:  # noqa: BLE001 - never an exception out of the Diagram
            self._Fail(inputs, st, t, f"arm_controller ({st.mode})", err)

    # --- helpers ---------------------------------------------------------------
    def _enter(self, st: ControllerStatus, mode: str, t: float, message: str = "") -> None:
        st.mode, st.t_mode = mode, t
        if message:
            st.message = message
        st.mode_log.append((round(t, 3), mode))
        self.progress(f"{mode}" + (f": {message}" if message else ""))

    def _start_path(self, st: ControllerStatus, t: float, waypoints: list, fraction: float,
                    duration: float | None = None, min_segment: float = 0.05,
                    rest_at_first: bool = False) -> None:
        q0 = st.trajectory.value(t).ravel() if st.trajectory is not None else st.q_hold
        st.trajectory = self.motions.TimePath(t, q0, waypoints, fraction, duration, min_segment,
                                              rest_at_first)
        st.q_hold = np.asarray(waypoints[-1], float)

    @staticmethod
    def _traj_done(st: ControllerStatus, t: float) -> bool:
        return st.trajectory is None or t >= st.trajectory.end_time()

    def _pull_duration(self, st: ControllerStatus, all_motions: bool = False) -> float:
        """Seconds for the current motion (or for all executed motions, to
        carry the leaf back) at the pull speed."""
        plans = st.plans if all_motions else st.plans[-1:]
        return self.motions.MotionDuration([p.chosen.action for p in plans])

    def _Stop(self, inputs: ArmInputs, st: ControllerStatus, t: float) -> None:
        """Holds the measured joints; the gripper keeps its current command
        (a ramp freezes where it is): a held leaf is never dropped."""
        st.gripper_cmd = GripperCommand(st, t)
        st.trajectory, st.gripper_ramp = None, None
        st.q_hold = inputs.measured_state()[:6].copy()

    def _Fail(self, inputs: ArmInputs, st: ControllerStatus, t: float, stage: str,
              err) -> None:
        """Holds the arm and aborts with status stage_error naming the stage."""
        self._Stop(inputs, st, t)
        st.failed_stage = stage
        self._enter(st, "aborted", t, f"stage_error: {stage}: {type(err).__name__}: "
                    f"{' '.join(str(err).split())}")

    # --- the modes -------------------------------------------------------------
    def _Idle(self, inputs: ArmInputs, st: ControllerStatus, t: float) -> None:
        if t - st.t_mode >= self._settle:
            st.captures = 1
            self._enter(st, "capture", t)

    def _Capture(self, inputs: ArmInputs, st: ControllerStatus, t: float) -> None:
        if inputs.views_fused() >= max(st.captures, 1):
            st.t_target, st.captures_plan = t, max(st.captures, 1)
            self._enter(st, "plan_requested", t)

    def _ConfirmWait(self, inputs: ArmInputs, st: ControllerStatus, t: float) -> None:
        if st.confirmed is True and st.pending_motion is not None:
            (plan, path), st.pending_motion = st.pending_motion, None
            self._StartContinuation(st, t, plan, path, "confirmed by the operator")
        elif st.confirmed is True:
            self._StartMotion(st, t, "confirmed by the operator")
        elif st.confirmed is False and st.pending_motion is not None:
            st.pending_motion = None
            self._StartRelease(st, t, "continuation not confirmed by the operator")
        elif st.confirmed is False:
            self._enter(st, "aborted", t, "not confirmed by the operator"
                        + (f" ({st.confirm_note})" if st.confirm_note else "")
                        + "; nothing moved")

    def _Pregrasp(self, inputs: ArmInputs, st: ControllerStatus, t: float) -> None:
        if self._traj_done(st, t):
            if not ZeroAtPregrasp(inputs, st, t):
                return                       # the arm settles before the zero is read
            path = st.segments.pop(0)
            self._start_path(st, t, path, **self.motions.ApproachTiming(st.q_hold, path))
            self._enter(st, "approach", t)

    def _Approach(self, inputs: ArmInputs, st: ControllerStatus, t: float) -> None:
        if self._traj_done(st, t):
            st.trajectory = None
            # Close slowly (gripper_close_speed), like the 2F-85 at low
            # speed, so the pads meet the leaf gently.
            st.gripper_ramp = (t, st.gripper_cmd, self._planner.grasp_close_width,
                               self._planner.gripper_close_speed)
            self._enter(st, "close_gripper", t)

    def _CloseGripper(self, inputs: ArmInputs, st: ControllerStatus, t: float) -> None:
        """Closed on the leaf when the pads stall (or reach the commanded
        opening); then hold that opening. Stalled on the leaf: what the
        gripper reports (the 2F-85's object detection), or, when it cannot
        tell (simulation), the pads closed less than 0.3 mm over the last
        STALL_WINDOW s while the command is more than 1 mm tighter."""
        width, rate, on_object = inputs.gripper_state()
        t0, w0, w1, speed = st.gripper_ramp
        commanded = max(w1, w0 - speed * (t - t0))
        st.grip_history = [(tt, ww) for tt, ww in st.grip_history
                           if t - tt <= STALL_WINDOW + 1e-9] + [(t, float(width))]
        old_t, old_w = st.grip_history[0]
        if np.isfinite(on_object):
            # The gripper tells: it stalled on the leaf, or its pads
            # stand at the end of the ramp with nothing between them.
            stalled = on_object >= 0.5
            if not stalled and t - t0 <= 2.0 and not (
                    commanded <= w1 + 1e-9 and width <= w1 + 0.0005 and abs(rate) < 0.001):
                return                      # still closing
            if not stalled:
                self._GraspMissed(st, t, width)
                return
        else:
            stalled = (t - old_t >= STALL_WINDOW - 1e-9 and old_w - width < 0.0003
                       and width > commanded + 0.001)
        if commanded <= w1 + 1e-9 or stalled or t - t0 > 2.0:
            # Stalled on the leaf: hold just inside the measured opening.
            # Otherwise the fingers may still lag the ramp: a request
            # above its last one would open a gripper that already holds
            # a thin leaf (the twin lets go; so would a 2F-85).
            st.gripper_ramp = None
            hold = float(width) - 0.0005
            st.gripper_cmd = max(w1, hold if stalled else min(commanded, hold))
            self._enter(st, "grasp_wait", t, f"closed at {max(0.0, width) * 1000:.1f} mm")

    def _GraspWait(self, inputs: ArmInputs, st: ControllerStatus, t: float) -> None:
        if st.grasp_acknowledged or not self._options.grasp_ack_required:
            if st.force_zero is None:
                f = inputs.wrist_force()
                st.force_zero = None if f is None else np.asarray(f, float).copy()
            st.force_peak, st.force_stop = 0.0, ""
            self._start_path(st, t, st.pull_path, 0.3, self._pull_duration(st))
            st.motion_paths = [st.pull_path]
            self._enter(st, "pull", t, st.plan.chosen.action.Describe())

    def _Pull(self, inputs: ArmInputs, st: ControllerStatus, t: float) -> None:
        if PullGuard(self, inputs, st, t):
            return
        if self._traj_done(st, t):
            self._enter(st, "hold", t)

    def _Hold(self, inputs: ArmInputs, st: ControllerStatus, t: float) -> None:
        if t - st.t_mode >= self._hold:
            st.captures += 1
            self._enter(st, "observe", t)

    def _Observe(self, inputs: ArmInputs, st: ControllerStatus, t: float) -> None:
        if inputs.views_fused() >= st.captures:
            t0 = time.perf_counter()
            st.final_estimate = _Stage("shape_reestimation", inputs.final_estimate)
            st.stage_seconds["reestimation_s"] = (
                st.stage_seconds.get("reestimation_s", 0.0) + time.perf_counter() - t0)
            if not self._Continue(inputs, st, t):
                self._StartRelease(st, t, "shape re-estimated on the fused views")

    def _Release(self, inputs: ArmInputs, st: ControllerStatus, t: float) -> None:
        """Once the leaf is carried back: open the pads ``ReleaseOpening``
        (m) past the measured opening; then, after the release time and
        once the pads report that opening (``PadsOpened``), back out."""
        width = inputs.gripper_state()[0]
        if not st.released and self._traj_done(st, t):
            st.trajectory = None
            st.gripper_cmd = ReleaseOpening(self._planner, st.pregrasp_opening, width)
            st.released, st.t_released = True, t
        elif st.released and t - st.t_released >= self._release_time / self._speed_scale \
                and PadsOpened(width, st.gripper_cmd, t - st.t_released):
            f = inputs.wrist_force()         # the way out's zero, the arm at rest
            self._StartRetreat(st, t, None if f is None else np.asarray(f, float).copy())

    def _Retreat(self, inputs: ArmInputs, st: ControllerStatus, t: float) -> None:
        if st.retreat_out and RetreatGuard(self, inputs, st, t):
            return
        if not self._traj_done(st, t):
            return
        st.retreat_out, st.retreat_zero = [], None      # out of the plant: unguarded
        if st.segments:
            waypoints, fraction = st.segments.pop(0)
            self._start_path(st, t, waypoints, fraction)
            return
        st.trajectory = None
        if st.grasp_missed:
            end, why, st.grasp_missed = "aborted", st.grasp_missed, ""
            outcome = why + "; arm retreated"
            message = why + "; gripper opened and arm retreated"
        else:
            message = ("action executed; shape re-estimated on the fused views; "
                       "leaf released and arm retreated")
            if st.force_stop:
                message = f"{st.force_stop}; " + message
            end, outcome = "done", "revealed: " + message
        if self._multi:         # the next fruit, from a fresh view
            self._EndTarget(st, t, outcome)
            st.captures += 1
            self._enter(st, "capture", t, f"{len(st.targets)} fruit(s) handled; "
                        "looking again for the next one")
        else:
            self._enter(st, end, t, message)

    # --- planning, and the motions it starts -----------------------------------
    def _Plan(self, inputs: ArmInputs, st: ControllerStatus, t: float) -> None:
        t0 = time.perf_counter()
        _Stage("perception", inputs.semantic_scene)
        t1 = time.perf_counter()
        st.initial_estimate = _Stage("shape_completion", inputs.scene_estimate)
        t2 = time.perf_counter()
        plan = _Stage("planning", inputs.plan)
        t3 = time.perf_counter()
        st.plan = plan
        st.stage_seconds.update(segmentation_s=t1 - t0, shape_completion_s=t2 - t1,
                                planning_s=t3 - t2)
        st.stage_seconds.update({k: v for k, v in plan.timings.items()})
        if plan.status == "no_action_needed":
            if not st.targets:
                st.final_estimate = st.initial_estimate
            self._enter(st, "done", t, "no action needed: " + plan.message)
            return
        if self._multi and plan.target is not None and plan.status == "no_feasible_action":
            # this fruit cannot be revealed: recorded, on to the next one
            st.final_estimate = st.initial_estimate
            self._EndTarget(st, t, f"{plan.status}: {plan.message}")
            st.t_target = t
            self._enter(st, "plan_requested", t, f"fruit {plan.target.get('fruit_id')}: no "
                        "feasible action; planning the next fruit")
            return
        if plan.status != "ok":
            if plan.status == "stage_error":
                st.failed_stage = plan.message.split(":")[0]
            self._enter(st, "aborted", t, f"{plan.status}: {plan.message}")
            return
        c = plan.chosen
        try:
            self._PathsFor(st, t, c)
        except (MotionError, Refused) as err:
            if not (self._multi and plan.target is not None):
                raise
            # this fruit's chosen motion cannot be executed: recorded, on to
            # the next fruit (nothing has moved)
            st.final_estimate = st.initial_estimate
            self._EndTarget(st, t, f"no_executable_path: {' '.join(str(err).split())}")
            st.t_target = t
            self._enter(st, "plan_requested", t, f"fruit {plan.target.get('fruit_id')}: the "
                        f"chosen motion cannot be executed ({err}); planning the next fruit")
            return
        summary = (f"grasp {c.action.grasp_id}, direction {c.action.direction_id}, "
                   f"{c.action.Describe()}")
        if self._options.plan_only:
            self._enter(st, "planned", t, f"plan only: {summary}; nothing moved")
        elif self._options.confirm:
            st.confirmed = None
            self._enter(st, "confirm_wait", t, summary)
        else:
            self._StartMotion(st, t, summary)

    def _PathsFor(self, st: ControllerStatus, t: float, c):
        """The joint paths of candidate ``c`` from the held joints (approach,
        action), stored in ``st`` and checked by timing them; raises
        ``MotionError`` (no IK or self-collision along them) or ``Refused``
        (the trajectory check). Returns the approach."""
        m = self.motions
        approach = m.Approach(c, st.q_hold)
        st.pull_path = m.ActionPath(c.action, approach.to_grasp[-1])
        st.segments = [approach.to_grasp]
        st.grasp_path = list(approach.to_grasp)
        st.pregrasp_path = [approach.via] + approach.to_ready + approach.to_pregrasp
        st.pregrasp_opening = approach.opening or self._pregrasp_opening
        # The whole motion is checked before anything moves (timing does not
        # depend on the start time, so the checks hold at execution).
        # (at rest at the via point: the free move there was checked on the
        # straight joint line)
        pre = m.TimePath(t, st.q_hold, st.pregrasp_path, 0.5, rest_at_first=True)
        app = m.TimePath(pre.end_time(), st.pregrasp_path[-1], approach.to_grasp,
                         **m.ApproachTiming(st.pregrasp_path[-1], approach.to_grasp))
        m.TimePath(app.end_time(), approach.to_grasp[-1], st.pull_path, 0.3,
                   self._pull_duration(st))
        return approach

    def _EndTarget(self, st: ControllerStatus, t: float, outcome: str) -> None:
        """Closes the current fruit's record (``targets``: its plan and
        target, the continuations, estimates before and after, the time
        window, the captures so far) and clears the per-target state."""
        st.targets = st.targets + [{
            "target": st.plan.target if st.plan is not None else None, "outcome": outcome,
            "plan": st.plan, "continuations": list(st.continuations),
            "replan_log": list(st.replan_log), "replan_results": list(st.replan_results),
            "initial_estimate": st.initial_estimate, "final_estimate": st.final_estimate,
            "t_start": st.t_target, "t_end": t, "captures": st.captures,
            "motions": len(st.motion_paths), "view_plan": st.captures_plan - 1,
            "view_after": st.captures - 1 if st.motion_paths else None,
            "stage_seconds": dict(st.stage_seconds), "force_stop": st.force_stop,
            "force_peak_N": st.force_peak}]
        st.force_zero, st.force_peak, st.force_stop = None, 0.0, ""
        st.continuations, st.replan_results, st.replan_log = [], [], []
        st.motion_paths, st.pull_path, st.segments = [], [], []
        st.grasp_path, st.pregrasp_path, st.grip_history = [], [], []
        st.released, st.t_released, st.grasp_acknowledged = False, 0.0, False
        st.confirmed, st.pending_motion, st.gripper_ramp = None, None, None

    def _StartRelease(self, st: ControllerStatus, t: float, message: str) -> None:
        """Back along every executed motion, still holding, so the leaf
        returns to rest in the gripper instead of springing back when let
        go (then ``release`` opens the gripper); without ``release`` the
        episode ends holding the leaf."""
        n = len(st.motion_paths)
        if not self._options.release:
            self._enter(st, "done", t, f"{n} motion(s) executed; {message}")
            return
        back = [q for path in st.motion_paths[::-1] for q in path[::-1]][1:]
        duration = self._pull_duration(st, all_motions=True)
        if st.force_stop:       # the last motion was stopped part way
            duration -= self._pull_duration(st) * (
                1.0 - ExecutedFraction(st.pull_path, st.motion_paths[-1]))
        self._start_path(st, t, back + [st.grasp_path[-1]], 0.3,
                         duration / self._planner.return_speed_scale)
        self._enter(st, "release", t, f"{n} motion(s) executed; {message}; "
                    "returning the leaf, then releasing it")

    def _Continue(self, inputs: ArmInputs, st: ControllerStatus, t: float) -> bool:
        """After observing: plan a further motion from the held leaf (at most
        ``planner.max_replans``); start it (or ask the operator) and return
        True, or return False to release. A continuation that cannot be
        planned or timed is not an error: the episode releases the leaf."""
        if len(st.continuations) >= self._max_replans or st.force_stop:
            return False
        t0 = time.perf_counter()
        if not inputs.has_continuation():
            return False
        plan = _Stage("continuation_planning", inputs.continuation)
        st.stage_seconds["replanning_s"] = (st.stage_seconds.get("replanning_s", 0.0)
                                            + time.perf_counter() - t0)
        st.replan_log = st.replan_log + [f"{plan.status}: {plan.message}"]
        st.replan_results = st.replan_results + [plan]
        if plan.status != "ok":
            self.progress(f"no further motion: {plan.message or plan.status}")
            return False
        a = plan.chosen.action
        try:
            path = self.motions.ActionPath(a, st.q_hold)
            self.motions.TimePath(t, st.q_hold, path, 0.3, self.motions.MotionDuration([a]))
        except (MotionError, Refused) as err:
            self.progress(f"no further motion: {err}")
            return False
        summary = f"continuation {len(st.continuations) + 1}: {a.Describe()}"
        if self._options.confirm:
            st.confirmed, st.pending_motion = None, (plan, path)
            self._enter(st, "confirm_wait", t, summary)
        else:
            self._StartContinuation(st, t, plan, path, summary)
        return True

    def _StartContinuation(self, st: ControllerStatus, t: float, plan: PlanResult,
                           path: list, message: str) -> None:
        st.continuations = st.continuations + [plan]
        st.pull_path = path
        st.motion_paths = st.motion_paths + [path]
        self._start_path(st, t, path, 0.3, self._pull_duration(st))
        self._enter(st, "pull", t, message)

    def _StartMotion(self, st: ControllerStatus, t: float, message: str) -> None:
        st.gripper_cmd = st.pregrasp_opening
        self._start_path(st, t, st.pregrasp_path, 0.5, rest_at_first=True)
        self._enter(st, "pregrasp", t, message)

    def _GraspMissed(self, st: ControllerStatus, t: float, width: float) -> None:
        """On hardware the gripper closed without reporting the leaf (no
        stall): nothing is held, so nothing is pulled. The gripper opens and
        the arm retreats; the target ends ``grasp missed`` (the episode
        aborts with that message, or the next fruit is planned)."""
        st.gripper_ramp = None
        st.gripper_cmd = st.pregrasp_opening
        w1 = self._planner.grasp_close_width
        st.grasp_missed = (f"grasp missed: the gripper closed to {max(0.0, width) * 1000:.1f} mm "
                           "without reporting the leaf between its pads; nothing was moved"
                           + (f" (the pads stop at planner.grasp_close_width, {w1 * 1000:.1f} "
                              "mm: a thinner leaf is never met, set it lower)"
                              if w1 > 0 and width <= w1 + 0.0005 else ""))
        self.progress(st.grasp_missed + "; opening and retreating")
        self._StartRetreat(st, t)

    def _StartRetreat(self, st: ControllerStatus, t: float,
                      force_zero: np.ndarray | None = None) -> None:
        """The approach in reverse (all of it checked at planning time):
        back out to the pre-grasp pose, through the ready and via poses,
        then the joint move to the episode's start pose. The way out to the
        pre-grasp is guarded (``arm_guard.RetreatGuard``; ``force_zero``:
        the wrist force at rest before it, else read at its first step)."""
        out = st.grasp_path[::-1][1:] + [st.pregrasp_path[-1]]
        st.segments = [(st.pregrasp_path[::-1][1:], 0.5), ([self._q_start.copy()], 0.5)]
        st.retreat_out, st.retreat_zero = [st.grasp_path[-1]] + out, force_zero
        # at the pull's pace: a leaf caught on the open gripper (one sprung
        # back around it while the leaf was held) is dragged slowly (337 N
        # at a petiole at the approach's 10 cm/s, 9.1 N at 3 cm/s), and the
        # tool's own inertia stays far below the retreat guard's limit
        self._start_path(st, t, out, **self.motions.ApproachTiming(
            st.q_hold, out, self.motions.pull_speed))
        self._enter(st, "retreat", t)

    def _BackOff(self, inputs: ArmInputs, st: ControllerStatus, t: float) -> None:
        if self._traj_done(st, t):
            BackOffDone(self, st, t)
