"""The real cell behind ``RunEpisode`` (``HardwareWorld``): the episode
Diagram on the hardware station (``station.hardware.station.
MakeHardwareStation``), stepped against the wall clock (periodic events
stand for time). A protective stop, an emergency stop, a lost link or a
refused command ends the episode with the arm stopped and the gripper left
as it is; no ground truth. Seconds.
"""
from __future__ import annotations

import time

from pydrake.systems.analysis import Simulator

from lmap_drake.diagram import EpisodeResources, MakeEpisodeDiagram
from lmap_drake.scenario import Scenario
from lmap_drake.station.hardware.station import MakeHardwareStation, StopHardwareStation


class HardwareWorld:
    """The real cell (or the project's fakes) behind ``RunEpisode``: the
    episode Diagram on ``MakeHardwareStation``, stepped against the wall
    clock at ``realtime_rate`` (0: as fast as it goes, for fakes)."""
    hardware = True

    def __init__(self, scenario: Scenario, resources: EpisodeResources, options, clients,
                 read_only: bool = False, realtime_rate: float = 1.0, progress=None):
        self.scenario = scenario
        self.clients = clients
        self.station = MakeHardwareStation(scenario, clients, read_only=read_only)
        self.diagram = MakeEpisodeDiagram(scenario, resources, self.station, options)
        self.simulator = Simulator(self.diagram)
        self.simulator.set_target_realtime_rate(0.0)   # paced here, see Step
        self.context = self.simulator.get_mutable_context()
        self.rate = float(realtime_rate)
        self.progress = progress or (lambda m: None)
        self._closed = False
        self.simulator.Initialize()
        self.Pause()

    @property
    def time(self) -> float:
        return self.context.get_time()

    def Start(self) -> None:
        self.Pause()

    def Pause(self) -> None:
        """Restarts the wall-clock pacing (after planning or a prompt: the
        run does not race to catch up)."""
        self._t0, self._wall0 = self.time, time.monotonic()

    def Step(self, dt: float) -> None:
        target = self.time + dt
        self.simulator.AdvanceTo(target)
        if self.rate > 0:
            delay = self._wall0 + (target - self._t0) / self.rate - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            elif delay < -0.25:      # a long computation (planning): do not catch up
                self.Pause()

    def AfterStep(self, controller, cctx, st) -> str:
        return ""

    def CurrentImages(self) -> dict:
        ctx = self.station.GetMyContextFromRoot(self.context)
        out = {}
        for name in ("rgb_image", "depth_image", "label_image"):
            image = self.station.GetOutputPort(f"camera0.{name}").Eval(ctx)
            copy_ = type(image)(image.width(), image.height())
            copy_.mutable_data[:] = image.data
            out[name] = copy_
        return out

    def Score(self, record: dict, views, st) -> None:
        record["outcome"] = None      # no ground truth on the real cell

    def Close(self) -> None:
        """Stops the arm and closes every client (the gripper is not moved)."""
        if not self._closed:
            self._closed = True
            StopHardwareStation(self.station)
