"""The simulated plant world behind ``RunEpisode`` (``SimWorld``): the
episode Diagram around the FEM plant station (``plants.plant_sim.
PlantWorldSim``), simulated as fast as it goes. It makes the grasp when the
pads close on the leaf (a rebuilt station with the leaf fixed to the
gripper), undoes it at release, and scores the episode against the ground
truth (``plants.scoring``). Also the Meshcat helpers of a simulated run:
``FrameMeshcat`` and ``LeafAnimator``. World frame W, metres, seconds.
"""
from __future__ import annotations

import numpy as np
from pydrake.geometry import Rgba

from lmap_drake.diagram import EpisodeResources, MakeEpisodeDiagram
from lmap_drake.plants.leaf import BoundaryTriangles
from lmap_drake.plants.plant_sim import PlantWorldSim
from lmap_drake.plants.plant_station import MakePlantStation
from lmap_drake.plants.scoring import ScoreEpisode
from lmap_drake.scenario import Scenario


def FrameMeshcat(meshcat, scenario: Scenario) -> None:
    """Points the Meshcat camera at the plant and the arm (not the whole
    floor): the target is midway between the robot base and the camera's
    view of the plant, seen from behind the scenario camera."""
    if meshcat is None:
        return
    p_WB = scenario.robot.X_WB.GetDeterministicValue().translation()
    X_WC = scenario.cameras["camera0"].X_PB.GetDeterministicValue()
    p_WPlant = X_WC.translation() + 0.55 * X_WC.rotation().col(2)   # ~ the plant
    target = 0.5 * (p_WB + p_WPlant) + np.array([0.0, 0.0, 0.1])
    eye = X_WC.translation() - 0.6 * X_WC.rotation().col(2) + np.array([-0.4, 0.0, 0.35])
    try:
        meshcat.SetCameraPose(eye, target)
    except Exception:  # noqa: BLE001 - older Meshcat without SetCameraPose
        pass


class SimWorld:
    """The simulated plant world behind ``RunEpisode`` (see the module
    docstring)."""
    hardware = False

    def __init__(self, scenario: Scenario, resources: EpisodeResources, options,
                 meshcat=None, progress=None):
        def make(s, m, grasp):
            diagram = MakeEpisodeDiagram(s, resources, MakePlantStation(s, m, grasp), options)
            return diagram, diagram.GetSubsystemByName("station")
        self.scenario = scenario
        self.sim = PlantWorldSim(scenario, meshcat, progress, make_diagram=make)
        self.model = self.sim.model
        self.progress = progress or (lambda m: None)
        self.animate = LeafAnimator(meshcat, self.sim)
        self.release_sample = None       # index into sim.samples where the release began
        self.vis_initial = None

    @property
    def diagram(self):
        return self.sim.diagram

    @property
    def context(self):
        return self.sim.context

    @property
    def time(self) -> float:
        return self.sim.time

    def Start(self) -> None:
        self.vis_initial = self.sim.Visibility()

    def Step(self, dt: float) -> None:
        self.sim.AdvanceTo(self.sim.time + dt)
        self.animate()

    def AfterStep(self, controller, cctx, st) -> str:
        """Makes the grasp as the pads close on the leaf (opening at most
        ``grasp_attach_opening``, before a fast squeeze can push the thin
        FEM leaf out) and undoes it at release. Returns an abort message or
        ''."""
        closing = st.mode == "close_gripper" and self.sim.GripperWidth() <= \
            self.scenario.planner.grasp_attach_opening
        if (closing or st.mode == "grasp_wait") and not st.grasp_acknowledged:
            try:
                self.sim.Grasp()
            except RuntimeError as err:
                return str(err)
            controller = self.diagram.GetSubsystemByName("arm_controller")
            controller.AcknowledgeGrasp(controller.GetMyContextFromRoot(self.context))
        if st.released and self.sim.grasp_state is not None:
            self.release_sample = len(self.sim.samples)
            self.sim.Release()
            self.progress("released the leaf")
        return ""

    def CurrentImages(self) -> dict:
        return self.sim.Images()

    def Pause(self) -> None:
        pass

    def Close(self) -> None:
        pass

    def Score(self, record: dict, views, st) -> None:
        """Ground truth (``plants.scoring.ScoreEpisode``): outcome flags (up
        to the release; the release and retreat separately), visibility in
        the two captured views (what the planner saw, and after the action),
        shape errors; with several fruits one entry per fruit."""
        self.vis_initial = ScoreEpisode(record, self.sim, self.scenario, views, st,
                                        self.vis_initial, self.release_sample)


class LeafAnimator:
    """Meshcat's recording does not animate deformable bodies: this adds the
    leaf's surface as a triangle mesh every ``period`` simulated seconds and
    toggles the snapshots' visibility in the recording, so the saved HTML
    shows the leaf moving."""

    def __init__(self, meshcat, world, period: float = 0.2):
        self.meshcat, self.world, self.period = meshcat, world, period
        model = world.model
        tets = ([leaf.tets for leaf in model.leaves] if hasattr(model, "leaves")
                else [model.leaf_tets])       # every leaf of a multi plant
        self.faces = [np.asarray(BoundaryTriangles(t), np.int32).T.copy() for t in tets]
        self.k, self.next_time, self.previous = 0, 0.0, None

    def __call__(self) -> None:
        t = self.world.time
        if self.meshcat is None or t < self.next_time:
            return
        path = f"/leaf_snapshots/{self.k:04d}"
        for j, faces in enumerate(self.faces):
            V = np.asarray(self.world.LeafVertices(j).T, float, order="F")
            self.meshcat.SetTriangleMesh(f"{path}/leaf_{j}", V, np.asfortranarray(faces),
                                         Rgba(0.2, 0.6, 0.15, 1.0))
        self.meshcat.SetProperty(path, "visible", False, 0.0)
        self.meshcat.SetProperty(path, "visible", True, t)
        if self.previous is not None:
            self.meshcat.SetProperty(self.previous, "visible", False, t)
        self.previous, self.k, self.next_time = path, self.k + 1, t + self.period
