"""LeafSystems wrapping the hardware clients (thin: ports, periodic events,
one call into a client).

Each system reads its device once when it is built (so that a default
Context already holds real measurements), again in an initialization event,
and then periodically. Exceptions from the clients (``HardwareAbort``,
``SafetyRefusal``) propagate out of ``Simulator.AdvanceTo`` unchanged.
Run a Diagram holding these systems with ``target_realtime_rate = 1``: the
periodic events stand for wall-clock time.
"""
from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import RenderLabel
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem
from pydrake.systems.sensors import CameraInfo, ImageDepth32F, ImageLabel16I, ImageRgba8U

from lmap_drake.station.hardware.robotiq_client import CheckOpeningCommand, OpeningToPos
from lmap_drake.station.hardware.safety import HardwareAbort


def _StopOnAbort(update, on_abort):
    """Wraps an event callback: on HardwareAbort, call ``on_abort`` (stop the
    arm) before re-raising, so a gripper or camera failure also stops it."""
    if on_abort is None:
        return update

    def wrapped(context, state):
        try:
            return update(context, state)
        except HardwareAbort:
            on_abort()
            raise
    return wrapped


class Ur5Driver(LeafSystem):
    """Input ``position`` (6, rad; optional: unconnected = send nothing);
    outputs ``position_measured`` (6), ``state_estimated`` (12: q, v) and
    ``wrist_force`` (3, N, base frame: the arm's TCP force estimate).
    Every ``period`` s: read the joint state, then hand the commanded
    position to the client (which checks it and streams it with servoJ).
    With ``command=False`` or a read-only client it only reads."""

    def __init__(self, client, period: float, command: bool = True):
        super().__init__()
        self.client = client
        self._period = float(period)
        self._command = command and client.control is not None
        q, v = client.ReadState()
        self._input = self.DeclareVectorInputPort("position", 6)
        self._x = self.DeclareDiscreteState(np.concatenate([q, v]))
        self._f = self.DeclareDiscreteState(np.asarray(client.ReadTcpForce(), float))
        self.DeclareInitializationDiscreteUpdateEvent(self._Read)
        self.DeclarePeriodicDiscreteUpdateEvent(self._period, 0.0, self._Update)
        self.DeclareVectorOutputPort("position_measured", 6, self._CalcQ,
                                     prerequisites_of_calc={self.xd_ticket()})
        self.DeclareStateOutputPort("state_estimated", self._x)
        self.DeclareStateOutputPort("wrist_force", self._f)

    def _Read(self, context, discrete_state) -> None:
        q, v = self.client.ReadState()
        discrete_state.set_value(self._x, np.concatenate([q, v]))
        discrete_state.set_value(self._f, np.asarray(self.client.ReadTcpForce(), float))

    def _Update(self, context, discrete_state) -> None:
        self._Read(context, discrete_state)
        if self._command and self._input.HasValue(context):
            self.client.SetTarget(self._input.Eval(context), self._period)

    def _CalcQ(self, context, output) -> None:
        output.SetFromVector(context.get_discrete_state(self._x).get_value()[:6])


class RobotiqDriver(LeafSystem):
    """Input ``position`` (1, opening m, 0 closed .. 0.085 open; optional);
    output ``state_measured`` (3: opening m, its rate m/s by finite
    difference over ``period``, and 1 when the gripper's OBJ register says it
    stopped on an object while closing, else 0; ``client.Measure`` reads
    the opening after the flag: the controller holds just inside it). A new
    ``SET POS`` is sent only when the commanded POS register value changes
    (``command=False``: never; the
    gripper is only read). ``on_abort`` is called before a
    HardwareAbort (a refused command, a lost link) leaves an event."""

    def __init__(self, client, period: float, on_abort=None, command: bool = True):
        super().__init__()
        self.client = client
        self._period = float(period)
        self._command = command
        self._input = self.DeclareVectorInputPort("position", 1)
        self._x = self.DeclareDiscreteState(np.array([client.Opening(), 0.0, 0.0]))
        self.DeclareInitializationDiscreteUpdateEvent(_StopOnAbort(self._Init, on_abort))
        self.DeclarePeriodicDiscreteUpdateEvent(self._period, 0.0,
                                                _StopOnAbort(self._Update, on_abort))
        self.DeclareStateOutputPort("state_measured", self._x)

    def _Init(self, context, discrete_state) -> None:
        discrete_state.set_value(self._x, np.array([self.client.Opening(), 0.0, 0.0]))

    def _Update(self, context, discrete_state) -> None:
        if self._command and self._input.HasValue(context):
            opening = CheckOpeningCommand(self._input.Eval(context))
            pos = OpeningToPos(opening, self.client.config)
            if pos != self.client.last_pos_sent:
                self.client.MoveToPos(pos)
        old = context.get_discrete_state(self._x).get_value()[0]
        new, obj = self.client.Measure()       # the opening no older than the object flag
        on_object = 1.0 if obj == 2 else 0.0   # stopped while closing
        discrete_state.set_value(self._x, np.array([new, (new - old) / self._period, on_object]))


def EmptyLabelImage(width: int, height: int) -> ImageLabel16I:
    """A label image with every pixel ``RenderLabel.kEmpty`` (no labels)."""
    return ImageLabel16I(width, height, int(RenderLabel.kEmpty))


class RealSenseCamera(LeafSystem):
    """Outputs ``rgb_image`` (ImageRgba8U), ``depth_image`` (ImageDepth32F,
    metres, +inf = no return) and ``label_image`` (ImageLabel16I, every pixel
    ``RenderLabel.kEmpty``: a real camera has no labels). Captures every
    ``period`` s. ``camera_info`` (device intrinsics) and ``X_WC`` (from the
    calibration file) are attributes. ``on_abort`` as for RobotiqDriver."""

    def __init__(self, client, period: float, X_WC: RigidTransform, on_abort=None):
        super().__init__()
        self.client = client
        self.X_WC = X_WC
        self.camera_info: CameraInfo = client.CameraInfo()
        w, h = self.camera_info.width(), self.camera_info.height()
        self._w, self._h = w, h
        rgb, depth = self._Capture()
        self._rgb = self.DeclareAbstractState(AbstractValue.Make(rgb))
        self._depth = self.DeclareAbstractState(AbstractValue.Make(depth))
        self._label = EmptyLabelImage(w, h)
        update = _StopOnAbort(self._Update, on_abort)
        self.DeclareInitializationUnrestrictedUpdateEvent(update)
        self.DeclarePeriodicUnrestrictedUpdateEvent(float(period), 0.0, update)
        self.DeclareAbstractOutputPort(
            "rgb_image", lambda: AbstractValue.Make(ImageRgba8U(w, h)),
            lambda c, out: out.set_value(c.get_abstract_state(self._rgb).get_value()),
            prerequisites_of_calc={self.abstract_state_ticket(self._rgb)})
        self.DeclareAbstractOutputPort(
            "depth_image", lambda: AbstractValue.Make(ImageDepth32F(w, h)),
            lambda c, out: out.set_value(c.get_abstract_state(self._depth).get_value()),
            prerequisites_of_calc={self.abstract_state_ticket(self._depth)})
        self.DeclareAbstractOutputPort(
            "label_image", lambda: AbstractValue.Make(ImageLabel16I(w, h)),
            lambda c, out: out.set_value(self._label),
            prerequisites_of_calc={self.nothing_ticket()})

    def _Capture(self) -> tuple[ImageRgba8U, ImageDepth32F]:
        rgba, metres = self.client.Capture()
        rgb = ImageRgba8U(self._w, self._h)
        rgb.mutable_data[:] = rgba
        depth = ImageDepth32F(self._w, self._h)
        depth.mutable_data[..., 0] = metres
        return rgb, depth

    def _Update(self, context, state) -> None:
        rgb, depth = self._Capture()
        state.get_mutable_abstract_state(self._rgb).set_value(rgb)
        state.get_mutable_abstract_state(self._depth).set_value(depth)
