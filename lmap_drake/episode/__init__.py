"""Episodes: one runner for the simulated and the hardware station.

- ``runner``: ``RunEpisode`` steps the episode Diagram until the
  ``ArmController`` is finished; ``RunLmapEpisode`` (``lmap-drake run``)
  and ``RunSimEpisode`` (one simulated episode, ``lmap-drake eval``).
- ``sim_world``: ``SimWorld``, the FEM plant world behind the runner
  (grasp made and undone in simulation, scored by ``plants.scoring``).
- ``hardware_world``: ``HardwareWorld``, the real cell behind the runner
  (paced by the wall clock; no ground truth).
- ``records``: what a run writes (``SaveEpisode``, ``PlanRecord``).
- ``figures``: the episode's pictures.
- ``replay``: ``ReplayRun`` re-plans offline on a run's recording
  (``lmap-drake replay``); ``bag_replay``: a RealSense / ROS bag's view
  converted into a recording and replayed (``lmap-drake replay BAG``).
- ``snapshots``: the station snapshot and the scripted pull of
  ``lmap-drake run``.

The names below are the entry points used by the command line and the
evaluation. World frame W, metres, seconds, radians.
"""
from lmap_drake.episode.records import EpisodeResult, SaveEpisode
from lmap_drake.episode.replay import ReplayRun
from lmap_drake.episode.runner import (HARDWARE_MAX_FRUITS, SECONDS_PER_FRUIT, ConsoleConfirm,
                                       EpisodeTimeLimit, RunEpisode, RunLmapEpisode,
                                       RunSimEpisode)
from lmap_drake.episode.snapshots import RunScriptedPullEpisode, RunStationSnapshot

__all__ = ["EpisodeResult", "SaveEpisode", "ReplayRun", "HARDWARE_MAX_FRUITS",
           "SECONDS_PER_FRUIT", "ConsoleConfirm", "EpisodeTimeLimit", "RunEpisode",
           "RunLmapEpisode", "RunSimEpisode", "RunScriptedPullEpisode", "RunStationSnapshot"]
