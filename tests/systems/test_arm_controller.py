"""The ArmController alone in a Diagram, its inputs fixed: a plan from the
synthetic planning scene and a continuation planned from the held leaf.
Checks the re-planning branch of the state machine: a further motion runs
from the held pose, asks the operator again with ``confirm``, and a refused
continuation releases the leaf along the motions already made."""
import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from lmap_drake.planning.continuation import PlanContinuation
from lmap_drake.scenario import Scenario
from lmap_drake.systems.arm_controller import ArmController, ControllerOptions
from lmap_drake.systems.arm_status import PADS_OPEN_TIMEOUT, PadsOpened, ReleaseOpening
from lmap_drake.types import SemanticScene
from tests.systems.test_planning_system import HeldAfterShortPull, _scene


@pytest.fixture(scope="module")
def plans():
    first, ctx, s, held = HeldAfterShortPull()
    cont = PlanContinuation(ctx, s.planner, s.deformation, held)
    assert cont.status == "ok", cont.message
    return first, cont


def _Run(plans, answers, max_replans=1, gripper=(0.003, 0.0, 1.0), grip_log=None,
         return_speed_scale=1.0, wrist_force=None, max_pull_force=10.0, state=None,
         max_retreat_force=3.0, release_opening=None, open_on_release=True):
    """``wrist_force(status, t)``: the station's wrist force (3, N) fixed
    on the port before each 0.1 s step (None: the port is left
    unconnected); ``state(status, t)``: the measured joints (12), likewise
    (None: the start pose at rest)."""
    first, cont = plans
    s = Scenario()
    s.planner.max_replans = max_replans
    s.planner.return_speed_scale = return_speed_scale
    s.planner.max_pull_force = max_pull_force
    s.planner.max_retreat_force = max_retreat_force
    if release_opening is not None:
        s.planner.release_opening = release_opening
    b = DiagramBuilder()
    log = []
    c = b.AddNamedSystem("arm_controller", ArmController(s, options=ControllerOptions(
        grasp_ack_required=False, confirm=True), progress=log.append))
    d = b.Build()
    sim = Simulator(d)
    ctx = sim.get_mutable_context()
    cc = c.GetMyMutableContextFromRoot(ctx)
    c.GetInputPort("plan").FixValue(cc, first)
    c.GetInputPort("continuation").FixValue(cc, cont)
    c.GetInputPort("semantic_scene").FixValue(cc, AbstractValue.Make(SemanticScene()))
    for name in ("scene_estimate", "final_estimate"):
        c.GetInputPort(name).FixValue(cc, AbstractValue.Make(_scene()))
    c.GetInputPort("ur5.state_estimated").FixValue(cc, np.r_[s.robot.initial_q, np.zeros(6)])
    follow = gripper if callable(gripper) else None
    c.GetInputPort("gripper.state_measured").FixValue(
        cc, follow(0.085, 0.085) if follow else list(gripper))     # default: on the leaf
    c.GetInputPort("views_fused").FixValue(cc, [10.0])
    asked, traj_ends = [], []
    answers = list(answers)
    while sim.get_context().get_time() < 60.0:
        if state is not None:
            c.GetInputPort("ur5.state_estimated").FixValue(
                cc, state(c.Status(cc), sim.get_context().get_time()))
        if wrist_force is not None:
            c.GetInputPort("ur5.wrist_force").FixValue(
                cc, wrist_force(c.Status(cc), sim.get_context().get_time()))
        if follow:
            w = c.GetInputPort("gripper.state_measured").Eval(cc)[0]
            cmd = float(c.GetOutputPort("gripper.position").Eval(cc)[0])
            c.GetInputPort("gripper.state_measured").FixValue(cc, follow(w, cmd))
        elif c.Status(cc).released and open_on_release:
            # the fixed gripper opens when told to let the leaf go
            cmd = float(c.GetOutputPort("gripper.position").Eval(cc)[0])
            c.GetInputPort("gripper.state_measured").FixValue(cc, [cmd, 0.0, 0.0])
        sim.AdvanceTo(sim.get_context().get_time() + 0.1)
        st = c.Status(cc)
        if grip_log is not None:
            grip_log.append((st.mode, float(c.GetOutputPort("gripper.position").Eval(cc)[0])))
        if st.trajectory is not None:
            traj_ends.append(np.asarray(st.q_hold, float).copy())
        if st.finished:
            break
        if st.mode == "confirm_wait" and st.confirmed is None:
            asked.append(st.pending_motion is not None)
            c.Confirm(cc, answers.pop(0))
    return c.Status(cc), asked, log


def test_a_continuation_runs_from_the_held_pose_after_a_second_yes(plans):
    st, asked, _ = _Run(plans, [True, True])
    modes = [m for _, m in st.mode_log]
    assert asked == [False, True]               # the plan, then the continuation
    assert modes.count("pull") == 2 and modes.count("confirm_wait") == 2
    assert modes[-3:] == ["release", "retreat", "done"]
    assert len(st.motion_paths) == 2 and len(st.continuations) == 1
    # the continuation starts where the first motion ended: its first
    # waypoint is one path step (<= 1 cm, <= 5 deg) from the held TCP pose
    from lmap_drake.planning.robot_model import RobotModel
    robot = RobotModel(Scenario().robot.X_WB.GetDeterministicValue())
    X_end, X_next = (robot.TcpPose(q) for q in (st.motion_paths[0][-1], st.motion_paths[1][0]))
    assert np.linalg.norm(X_next.translation() - X_end.translation()) <= 0.0105
    assert X_end.rotation().InvertAndCompose(X_next.rotation()).ToAngleAxis().angle() \
        <= np.deg2rad(5.1)
    assert st.stage_seconds["replanning_s"] >= 0.0
    assert len(st.replan_log) == 1 and st.replan_log[0].startswith("ok")


def test_a_refused_continuation_releases_the_leaf(plans):
    st, asked, log = _Run(plans, [True, False])
    modes = [m for _, m in st.mode_log]
    assert asked == [False, True]
    assert modes.count("pull") == 1 and modes[-3:] == ["release", "retreat", "done"]
    assert len(st.motion_paths) == 1 and st.mode == "done"
    assert any(m.startswith("release: 1 motion(s) executed; continuation not confirmed")
               for m in log), log


def test_no_replans_means_one_motion(plans):
    st, asked, _ = _Run(plans, [True], max_replans=0)
    assert asked == [False] and [m for _, m in st.mode_log].count("pull") == 1
    assert st.replan_log == [] and st.mode == "done"


def test_the_leaf_is_carried_back_at_return_speed_scale_times_the_pull_pace(plans):
    def Seconds(st, mode):
        log = st.mode_log
        return next(log[i + 1][0] - t for i, (t, m) in enumerate(log) if m == mode)
    runs = [_Run(plans, [True], max_replans=0, return_speed_scale=k)[0] for k in (1.0, 2.0)]
    pull = [Seconds(st, "pull") for st in runs]
    back = [Seconds(st, "release") - 0.5 for st in runs]     # minus the open gripper's wait
    assert pull[0] == pytest.approx(pull[1], abs=0.11)
    assert back[0] == pytest.approx(pull[0], abs=0.21)       # the test steps every 0.1 s
    assert back[1] == pytest.approx(0.5 * back[0], abs=0.21)


def _Lagging(w: float, cmd: float):
    """Fingers that close a third of the way to the request every 0.1 s
    (no object flag: simulation), so they lag the closing ramp."""
    w_next = w + (cmd - w) / 3.0
    return [w_next, (w_next - w) / 0.1, np.nan]


def test_closing_never_asks_the_gripper_to_open(plans):
    """The fingers lag the closing ramp: when the ramp reaches its end the
    controller still reads several mm. Holding "just inside the measured
    opening" must not raise the request above the ramp's (a request that
    rises opens a real 2F-85 and drops a thin leaf; the twin let go)."""
    log = []
    st, _, _ = _Run(plans, [True, True], gripper=_Lagging, grip_log=log)
    closing = [w for m, w in log if m in ("close_gripper", "grasp_wait", "pull", "hold")]
    assert len(closing) > 5 and "pull" in [m for m, _ in log]
    assert all(b <= a + 1e-9 for a, b in zip(closing, closing[1:])), closing
    assert closing[-1] <= Scenario().planner.grasp_close_width + 1e-9


def _RisingInPull(rate: float):
    """A wrist force that reads the tool's weight, then rises ``rate`` N/s
    from the start of the first pull (the leaf loaded as it moves) and is
    the weight again once the leaf is carried back."""
    start = []

    def force(st, t):
        if st.mode == "pull" and not start:
            start.append(t)
        loaded = start and st.mode in ("pull", "hold", "observe", "confirm_wait")
        return np.array([rate * (t - start[0]) if loaded else 0.0, 0.0, -9.1])
    return force


def test_the_force_guard_stops_the_pull_and_returns_what_was_executed(plans):
    st, asked, log = _Run(plans, [True, True], wrist_force=_RisingInPull(20.0))
    modes = [m for _, m in st.mode_log]
    assert len(st.force_stops) == 1 and st.force_stops[0]["rise_N"] > 10.0
    assert st.force_stops[0]["rise_N"] < 10.0 + 20.0 * 0.15   # stopped within a step or two
    # stopped before the planned motion ended: the executed part (what is
    # carried back) is shorter and ends short of the planned end
    executed, planned = st.motion_paths[0], st.pull_path
    assert len(executed) < len(planned)
    assert np.linalg.norm(np.asarray(executed[-1]) - np.asarray(planned[-1])) > 1e-3
    assert modes[modes.index("pull") + 1] == "hold"
    # no continuation after a stop (the operator was asked once: the plan)
    assert asked == [False] and not st.continuations
    assert modes[-3:] == ["release", "retreat", "done"]
    assert "force guard" in st.message and "10 N" in st.message


def test_the_executed_part_ends_where_the_arm_stopped(plans):
    from lmap_drake.systems.arm_guard import ExecutedPart
    path = [np.full(6, 0.1 * k) for k in range(1, 11)]
    part = ExecutedPart(path, np.full(6, 0.42))       # past 0.4: kept
    assert len(part) == 5 and np.allclose(part[-1], 0.42) and np.allclose(part[-2], 0.4)
    part = ExecutedPart(path, np.full(6, 0.38))       # short of 0.4: not kept
    assert len(part) == 4 and np.allclose(part[-2], 0.3)
    assert len(ExecutedPart([], np.zeros(6))) == 1
    from lmap_drake.systems.arm_guard import ExecutedFraction
    assert ExecutedFraction(path, ExecutedPart(path, np.full(6, 0.55))) == pytest.approx(0.5)
    assert ExecutedFraction(path, path) == 1.0 and ExecutedFraction([path[0]], []) == 1.0


def test_a_load_below_the_limit_or_a_guard_off_never_stops(plans):
    for rate, limit in [(2.0, 10.0), (20.0, 0.0)]:
        st, asked, _ = _Run(plans, [True, True], wrist_force=_RisingInPull(rate),
                            max_pull_force=limit)
        assert not st.force_stops and asked == [False, True]
        assert st.force_peak > 0.5       # measured all the same


def test_a_retreat_that_drags_a_leaf_goes_back_and_aborts(plans):
    """A leaf caught on the open gripper: the wrist force rises as the arm
    backs out; the arm goes back to where it released the leaf (the
    grasp pose) and the episode aborts there, saying why."""
    start = []

    def force(st, t):
        if st.mode == "retreat" and not start:
            start.append(t)
        return np.array([0.0, 40.0 * (t - start[0]) if start else 0.0, -9.1])
    st, asked, _ = _Run(plans, [True, False], wrist_force=force)
    modes = [m for _, m in st.mode_log]
    assert modes[-3:] == ["retreat", "back_off", "aborted"]
    assert [s["motion"] for s in st.force_stops] == ["retreat"]
    assert "caught on the gripper" in st.message and "free the leaf" in st.message
    assert np.allclose(st.q_hold, st.grasp_path[-1])      # back where it let go
    # still open as far as the release opened it: planner.release_opening
    # past the opening measured on the leaf (the fake gripper's 3 mm)
    assert st.gripper_cmd == pytest.approx(0.003 + Scenario().planner.release_opening)


def test_the_pads_open_only_as_far_as_the_release_opening(plans):
    """At the release the pads open ``planner.release_opening`` (1 cm) past
    the opening measured on the leaf (the fake gripper's 3 mm), not to the
    approach's 3.5 cm: each pad moves 5 mm, so a leaf that came to lie
    beside a pad while the held one was moved is pushed that far, not
    1.7 cm; 0 opens them to the approach's opening, as before. The way
    out waits for the pads to report the opening (``PadsOpened``): a
    gripper that never does is waited for ``PADS_OPEN_TIMEOUT``."""
    seen = {}

    def force(st, t):
        if st.mode in ("release", "retreat"):
            seen.setdefault(st.mode, st.gripper_cmd)
        return np.array([0.0, 0.0, -9.1])
    for w in (None, 0.0):
        seen.clear()
        st, _, _ = _Run(plans, [True, False], wrist_force=force, release_opening=w)
        assert st.mode == "done"
        want = st.pregrasp_opening if w == 0.0 else 0.003 + Scenario().planner.release_opening
        assert seen["retreat"] == pytest.approx(want)
        assert want == pytest.approx(0.013 if w is None else 0.035)
    waits = []
    for opens in (True, False):
        st, _, _ = _Run(plans, [True, False], open_on_release=opens)
        log = st.mode_log
        t_rel = next(t for t, m in log if m == "release")
        t_out = next(t for t, m in log if m == "retreat")
        waits.append(t_out - t_rel)
    assert PADS_OPEN_TIMEOUT - 0.5 - 0.21 <= waits[1] - waits[0] <= PADS_OPEN_TIMEOUT - 0.5 + 0.21


def test_the_release_opening_counts_from_the_leaf_and_stays_within_the_approach():
    cfg = Scenario().planner                                  # release_opening 1 cm
    assert ReleaseOpening(cfg, 0.035, 0.004) == pytest.approx(0.014)
    assert ReleaseOpening(cfg, 0.035, 0.030) == pytest.approx(0.035)   # never wider
    assert ReleaseOpening(cfg, 0.035, float("nan")) == pytest.approx(0.010)
    assert ReleaseOpening(cfg, 0.035, -0.001) == pytest.approx(0.010)
    cfg.release_opening = 0.0
    assert ReleaseOpening(cfg, 0.035, 0.004) == pytest.approx(0.035)   # the old behaviour


def test_the_way_out_waits_for_the_pads_to_open():
    assert not PadsOpened(0.003, 0.013, 0.6)          # still on the leaf
    assert PadsOpened(0.0125, 0.013, 0.6)             # open (within 1 mm)
    assert PadsOpened(0.003, 0.013, PADS_OPEN_TIMEOUT)  # gave up waiting
    assert PadsOpened(float("nan"), 0.013, 0.6)       # no measured opening


def test_a_grasp_that_already_loads_the_leaf_counts_against_the_limit(plans):
    """The zero is read at the pre-grasp pose: closing the pads on the leaf
    (pressing it, or a neighbour) adds 6 N before the pull; the pull's own
    10 N/s then reaches the 10 N limit within about 0.4 s, not 1 s."""
    pull = []

    def force(st, t):
        if st.mode == "pull" and not pull:
            pull.append(t)
        loaded = st.mode in ("close_gripper", "grasp_wait", "pull", "hold", "observe")
        rise = (6.0 if loaded else 0.0) + (10.0 * (t - pull[0]) if pull and loaded else 0.0)
        return np.array([0.0, rise, -9.1])
    st, _, _ = _Run(plans, [True, True], wrist_force=force)
    assert len(st.force_stops) == 1
    assert st.force_stops[0]["t"] - pull[0] < 0.6


def test_the_zero_waits_for_the_arm_to_settle_at_the_pre_grasp_pose(plans):
    """As the fast move to the pre-grasp pose ends, the arm still moves and
    the tool's inertia reads 12 N: the zero is read only once the joints
    are still, so a gentle pull (2 N/s) is not stopped."""
    ended = []
    q0 = Scenario().robot.initial_q

    def moving(st, t):
        # (the ports are fixed for 0.1 s steps: moving from a step before
        # the move's end)
        if st.mode == "pregrasp" and st.trajectory is not None and not ended:
            ended.append(st.trajectory.end_time())
        return bool(ended) and ended[0] - 0.1 <= t < ended[0] + 0.35

    def state(st, t):
        return np.r_[q0, np.full(6, 0.05 if moving(st, t) else 0.0)]

    rising = _RisingInPull(2.0)

    def force(st, t):
        return rising(st, t) + [0.0, 12.0 if moving(st, t) else 0.0, 0.0]
    st, _, _ = _Run(plans, [True, True], wrist_force=force, state=state)
    assert ended and not st.force_stops
    modes = dict((m, tt) for tt, m in reversed(st.mode_log))
    assert modes["approach"] - ended[0] >= 0.3       # it waited for the arm


def test_the_retreat_guard_ignores_a_one_sample_spike_and_stops_on_a_lasting_rise():
    """The retreat guard acts on the median of the last
    ``RETREAT_WINDOW`` rises: the tool's inertia under a burst of commands
    reads as one sample, a caught leaf as a rise that lasts."""
    from types import SimpleNamespace
    from lmap_drake.systems.arm_guard import RETREAT_WINDOW, RetreatGuard
    entered = []
    seq = SimpleNamespace(_planner=SimpleNamespace(max_retreat_force=8.0),
                          _start_path=lambda *a, **k: None, _enter=lambda st, m, t, why: entered.append(m),
                          motions=SimpleNamespace(ApproachTiming=lambda *a: {}, pull_speed=0.05))
    force = [np.zeros(3)]
    inputs = SimpleNamespace(wrist_force=lambda: force[0], measured_state=lambda: np.zeros(12))
    st = SimpleNamespace(trajectory=object(), retreat_zero=None, force_trace=[], retreat_peak=0.0,
                         retreat_out=[np.zeros(6), np.ones(6)], segments=[], force_stops=[],
                         targets=[], q_hold=None)
    t = 0.0
    assert not RetreatGuard(seq, inputs, st, t)          # the zero
    for f in [2.0] * RETREAT_WINDOW + [16.7, 2.4, 2.4, 2.4]:
        t += 0.02
        force[0] = np.array([f, 0.0, 0.0])
        assert not RetreatGuard(seq, inputs, st, t), f
    assert st.retreat_peak > 16.0 and not entered        # the spike is logged, not acted on
    stops = []
    for _ in range(RETREAT_WINDOW):
        t += 0.02
        force[0] = np.array([12.0, 0.0, 0.0])
        stops.append(RetreatGuard(seq, inputs, st, t))
        if stops[-1]:
            break
    assert stops[-1] and len(stops) == RETREAT_WINDOW // 2 + 1 and entered == ["back_off"]


def test_a_stop_eases_the_command_to_rest_from_where_it_stands():
    """``EaseToRest``: no jump in the commanded joints or their speed at the
    stop (a jump back to the measured joints read as a backward velocity
    and jerked the held leaf), at rest ``STOP_TIME`` later, half the speed
    times that further along."""
    from pydrake.trajectories import PiecewisePolynomial
    from lmap_drake.systems.arm_guard import STOP_TIME, EaseToRest
    q0, q1 = np.zeros(6), np.linspace(0.1, 0.6, 6)
    traj = PiecewisePolynomial.CubicWithContinuousSecondDerivatives(
        [0.0, 1.0, 2.0], np.c_[q0, 0.5 * (q0 + q1), q1], np.zeros(6), np.zeros(6))
    t = 0.7
    ease, q_end = EaseToRest(traj, t)
    v = traj.EvalDerivative(t, 1).ravel()
    assert np.abs(v).max() > 0.1
    assert np.allclose(ease.value(t).ravel(), traj.value(t).ravel())
    assert np.allclose(ease.EvalDerivative(t, 1).ravel(), v)
    assert ease.end_time() == pytest.approx(t + STOP_TIME)
    assert np.allclose(ease.EvalDerivative(t + STOP_TIME, 1).ravel(), 0.0, atol=1e-9)
    assert np.allclose(q_end, traj.value(t).ravel() + 0.5 * STOP_TIME * v)
    assert np.allclose(ease.value(t + STOP_TIME).ravel(), q_end)
    # past its end the trajectory stands still: the ease starts at rest there
    _, q_rest = EaseToRest(traj, 2.5)
    assert np.allclose(q_rest, q1)
