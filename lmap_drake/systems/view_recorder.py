"""``ViewRecorder``: the views the episode asked for, held as they were seen
(thin shell around ``lmap_drake.perception.recording``); ``RecordedViews``:
the same outputs played back from a recording (``lmap-drake replay``).

ViewRecorder input ports:

- ``camera0.rgb_image`` (ImageRgba8U), ``camera0.depth_image``
  (ImageDepth32F, metres along the optical axis), ``camera0.label_image``
  (ImageLabel16I, optional; simulation labels);
- ``ur5.state_estimated`` (12: q rad, v rad/s), ``gripper.state_measured``
  (3: opening m, rate m/s, object flag);
- ``capture`` (1): how many views the episode wants. When it exceeds the
  number held, the current images and joint state are captured at the start
  of the next simulation step (per-step unrestricted update).

Output ports (both systems):

- ``rgb_image``, ``depth_image``, ``label_image``: the newest captured view
  (empty 0x0 images before the first capture);
- ``ur5.position`` (6, rad): the joints at the newest capture (before the
  first one: the measured joints, passed through; RecordedViews: view 0's);
- ``gripper.opening`` (1, m): the gripper's opening at the newest capture
  (NaN: unknown; before the first capture: the measured one, passed
  through);
- ``num_views`` (1): views held;
- ``views`` (abstract ``ViewLog``): all captured views, oldest first.
"""
from __future__ import annotations

import time

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import EventStatus, LeafSystem
from pydrake.systems.sensors import ImageDepth32F, ImageLabel16I, ImageRgba8U

from lmap_drake.perception.recording import CapturedView, ViewLog


def ViewImages(view: CapturedView | None):
    """(ImageRgba8U, ImageDepth32F, ImageLabel16I) of a captured view (empty
    images for None; labels all ``kEmpty`` when the view has none)."""
    if view is None:
        return ImageRgba8U(), ImageDepth32F(), ImageLabel16I()
    h, w = view.depth.shape
    rgb, depth, label = ImageRgba8U(w, h), ImageDepth32F(w, h), ImageLabel16I(w, h)
    rgb.mutable_data[:] = view.rgb
    depth.mutable_data[..., 0] = view.depth
    if view.label is not None:
        label.mutable_data[..., 0] = view.label
    else:
        from pydrake.geometry import RenderLabel
        label.mutable_data[:] = int(RenderLabel.kEmpty)
    return rgb, depth, label


class _ViewOutputs(LeafSystem):
    """Declares the shared output ports over ``self._Log(context)``."""

    def _DeclareOutputs(self, log_ticket) -> None:
        deps = {log_ticket}
        for i, (name, make) in enumerate((("rgb_image", ImageRgba8U),
                                          ("depth_image", ImageDepth32F),
                                          ("label_image", ImageLabel16I))):
            self.DeclareAbstractOutputPort(
                name, lambda make=make: AbstractValue.Make(make()),
                lambda c, out, i=i: out.set_value(self._Newest(c)[i]),
                prerequisites_of_calc=deps)
        self.DeclareVectorOutputPort("ur5.position", 6, self._CalcQ,
                                     prerequisites_of_calc=self._QDeps(log_ticket))
        self.DeclareVectorOutputPort("gripper.opening", 1, self._CalcOpening,
                                     prerequisites_of_calc=self._QDeps(log_ticket))
        self.DeclareVectorOutputPort(
            "num_views", 1, lambda c, out: out.SetFromVector([len(self._Log(c))]),
            prerequisites_of_calc=deps)
        self.DeclareAbstractOutputPort(
            "views", lambda: AbstractValue.Make(ViewLog()),
            lambda c, out: out.set_value(self._Log(c)), prerequisites_of_calc=deps)

    def _Newest(self, context):
        log = self._Log(context)
        view = log[-1] if log else None
        cached = getattr(self, "_cache", None)
        if cached is None or cached[0] is not view:   # keeps the view alive: `is` is safe
            self._cache = cached = (view, ViewImages(view))
        return cached[1]

    def _QDeps(self, log_ticket):
        return {log_ticket}

    def _CalcQ(self, context, output) -> None:
        log = self._Log(context)
        output.SetFromVector(log[-1].q)

    def _CalcOpening(self, context, output) -> None:
        log = self._Log(context)
        output.SetFromVector([log[-1].gripper[0] if log else np.nan])


class ViewRecorder(_ViewOutputs):
    """See the module docstring."""

    def __init__(self):
        super().__init__()
        self._rgb = self.DeclareAbstractInputPort("camera0.rgb_image",
                                                  AbstractValue.Make(ImageRgba8U()))
        self._depth = self.DeclareAbstractInputPort("camera0.depth_image",
                                                    AbstractValue.Make(ImageDepth32F()))
        self._label = self.DeclareAbstractInputPort("camera0.label_image",
                                                    AbstractValue.Make(ImageLabel16I()))
        self._x = self.DeclareVectorInputPort("ur5.state_estimated", 12)
        self._g = self.DeclareVectorInputPort("gripper.state_measured", 3)
        self._capture = self.DeclareVectorInputPort("capture", 1)
        self._log = self.DeclareAbstractState(AbstractValue.Make(ViewLog()))
        self._DeclareOutputs(self.abstract_state_ticket(self._log))
        self.DeclarePerStepUnrestrictedUpdateEvent(self._OnStep)

    def _Log(self, context) -> ViewLog:
        return context.get_abstract_state(self._log).get_value()

    def _QDeps(self, log_ticket):
        return {log_ticket, self._x.ticket(), self._g.ticket()}

    def _CalcQ(self, context, output) -> None:
        log = self._Log(context)
        output.SetFromVector(log[-1].q if log else self._x.Eval(context)[:6])

    def _CalcOpening(self, context, output) -> None:
        log = self._Log(context)
        if log:
            output.SetFromVector([log[-1].gripper[0]])
        else:
            output.SetFromVector([self._g.Eval(context)[0] if self._g.HasValue(context)
                                  else np.nan])

    def Capture(self, context) -> CapturedView:
        """The current view (copies of the images and the joint state)."""
        label = None
        if self._label.HasValue(context):
            from pydrake.geometry import RenderLabel
            data = np.array(self._label.Eval(context).data[..., 0], np.int16)
            if data.size and not np.all(data == int(RenderLabel.kEmpty)):
                label = data
        x = self._x.Eval(context)
        g = self._g.Eval(context) if self._g.HasValue(context) else np.full(3, np.nan)
        return CapturedView(len(self._Log(context)), context.get_time(), time.time(),
                            np.array(self._rgb.Eval(context).data, np.uint8),
                            np.array(self._depth.Eval(context).data[..., 0], np.float32),
                            label, np.array(x[:6]), np.array(x[6:]), np.array(g, float))

    def _OnStep(self, context, state):
        if not self._capture.HasValue(context):
            return EventStatus.DidNothing()
        log = self._Log(context)
        if self._capture.Eval(context)[0] <= len(log):
            return EventStatus.DidNothing()
        state.get_mutable_abstract_state(self._log).set_value(log.Add(self.Capture(context)))
        return EventStatus.Succeeded()


class RecordedViews(_ViewOutputs):
    """Plays back recorded views: holds the first ``num_views`` of them
    (default 1, the view planning used)."""

    def __init__(self, views, num_views: int = 1):
        super().__init__()
        if not 1 <= num_views <= len(views):
            raise ValueError(f"num_views {num_views} not in 1..{len(views)}")
        self._views = ViewLog(tuple(views[:num_views]))
        self._DeclareOutputs(self.nothing_ticket())

    def _Log(self, context) -> ViewLog:
        return self._views
