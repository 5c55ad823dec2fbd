"""The simulated plant world as one object: the station Diagram, its
Simulator, joint-space motions, the grasp mechanism and the ground-truth
monitors.

Grasping: Drake cannot switch a deformable fixed constraint on or off during
a run, so when the gripper has closed on the leaf, ``Grasp()`` rebuilds the
station with a fixed constraint between the gripper base and the leaf
vertices lying between the pads, and carries the whole state (time, rigid and
deformable positions and velocities, servo states) over to the new Diagram.
The constraint's reference placement is the rigid fit of those vertices'
reference positions to their current ones, so the grasp does not jolt the
leaf. ``Release()`` goes back to the station without it (built once and
kept), carrying the state over the same way.

The scripted motions on it (grasp poses, approach and grasp, pull, the
scripted pull) are in ``plants.scripted``; the ground-truth scoring of an
episode in ``plants.scoring``.
"""
from __future__ import annotations

import copy
import dataclasses as dc
from typing import Callable

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.analysis import Simulator
from pydrake.trajectories import PiecewisePolynomial

from lmap_drake.plants.generator import SIGN_RAYS, MeshSignedDistance
from lmap_drake.plants.leaf import MaxPrincipalStretch, RestShapeInverse
from lmap_drake.plants.leaf_sleep import LeafProximity
from lmap_drake.plants.multi import MULTI_KINDS
from lmap_drake.plants.outcome import (ConstrainedTetMask, OutcomeSample, PetioleForce,
                                       RobotLeafContactForces, StrainPercentile,
                                       VisibilityFraction)
from lmap_drake.plants.plant_station import (GetPlantModel, LeafGrasp, MakePlantStation,
                                             UnoccludedFruitPixels)
from lmap_drake.scenario import Scenario
from lmap_drake.robot import GRIPPER_MAX_WIDTH


def SetFemThreads(plant, threads: int = 0) -> int:
    """Threads for ``plant``'s FEM (0 = ``DefaultWorkers()``); returns the
    number set, or 0 when this Drake has no such hook (then serial).
    Drake's ``DeformableModel`` parallelism is bound as an internal method
    (``_set_parallelism``); the leaves' results do not depend on it."""
    from lmap_drake.parallel import DefaultWorkers
    dm = plant.deformable_model()
    if not hasattr(dm, "_set_parallelism"):
        return 0
    from pydrake.common import Parallelism
    n = int(threads) or DefaultWorkers()
    dm._set_parallelism(Parallelism(n))
    return n


def _Kabsch(P: np.ndarray, Q: np.ndarray) -> RigidTransform:
    """Rigid transform T minimising |T P - Q| (rows are points)."""
    cp, cq = P.mean(0), Q.mean(0)
    H = (P - cp).T @ (Q - cq)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1, 1, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return RigidTransform(RotationMatrix(R), cq - R @ cp)


@dc.dataclass
class GraspState:
    grasp: LeafGrasp
    vertices: np.ndarray  # leaf vertex indices held by the gripper (of leaf grasp.leaf)


@dc.dataclass
class _LeafRef:
    """One leaf's reference mesh (world, m) as the sim needs it."""
    rest_W: np.ndarray
    tets: np.ndarray
    uv: np.ndarray
    fixed: np.ndarray


def _LeafRefs(model) -> list[_LeafRef]:
    if hasattr(model, "leaves"):     # MultiPlantModel
        return [_LeafRef(x.rest_W, x.tets, x.uv, x.fixed) for x in model.leaves]
    return [_LeafRef(model.leaf_rest_W, model.leaf_tets, model.leaf_uv, model.leaf_fixed)]


class PlantWorldSim:
    """Simulated UR5 + FEM-leaf plant, driven through the station's ports.

    ``plant_scene.kind: procedural`` (one leaf, ``model`` a ``PlantModel``)
    or ``multi`` (leaves ``leaf_0`` ... , ``model`` a ``MultiPlantModel``;
    ``LeafVertices(j)``, ``Visibility(fruit=i)``; the outcome measures take
    the worst leaf and fruit).

    ``progress`` receives short status strings. Times in seconds, joint
    angles in radians, openings in metres."""

    def __init__(self, scenario: Scenario, meshcat=None,
                 progress: Callable[[str], None] | None = None, make_diagram=None):
        """``make_diagram(scenario, meshcat, leaf_grasp) -> (root, station)``
        builds the simulated Diagram (default: the station alone, driven
        through its input ports by this object)."""
        if scenario.plant_scene.kind not in ("procedural",) + MULTI_KINDS:
            raise ValueError("PlantWorldSim needs plant_scene.kind: procedural, multi or "
                             "greenhouse")
        self.multi = scenario.plant_scene.kind in MULTI_KINDS
        self.scenario = scenario
        self.meshcat = meshcat
        self._make_diagram = make_diagram
        self.model = GetPlantModel(scenario)
        self.progress = progress or (lambda msg: None)
        self.X_WB = scenario.robot.X_WB.GetDeterministicValue()
        from lmap_drake.planning.robot_model import RobotModel
        self.robot = RobotModel(self.X_WB)
        self.q_cmd = np.asarray(scenario.robot.initial_q, float)
        self.width_cmd = float(scenario.robot.initial_gripper_width)
        self.samples: list[OutcomeSample] = []
        self._asleep_measures: dict[int, tuple] = {}   # frozen leaves: (strain, force, pen)
        self._frozen: dict[int, LeafProximity] = {}     # frozen leaves: their vertices' bounds
        # the largest robot-robot / robot-branch contact so far, and what touched
        self.worst_robot_contact = {"force_N": 0.0, "t": None, "pair": ""}
        self.grasp_state: GraspState | None = None
        self._unoccluded: dict = {}
        self.leaf_refs = _LeafRefs(self.model)
        # The petiole's force is read one ring of tets away from the fixed
        # vertices (the ring that touches them is a stress singularity).
        self._petiole_tets_of = []
        for ref in self.leaf_refs:
            ring1 = ConstrainedTetMask(ref.tets, np.flatnonzero(ref.fixed))
            self._petiole_tets_of.append(
                ConstrainedTetMask(ref.tets, np.unique(ref.tets[ring1])) & ~ring1)
        self._petiole_tets = self._petiole_tets_of[0]
        self._Dm_inv_of: list = [None] * len(self.leaf_refs)   # per leaf, when first measured
        self._free = None        # (diagram, station, simulator) without a grasp, kept
        self._build(None, None)

    @property
    def num_leaves(self) -> int:
        return len(self.leaf_refs)

    # --- building and state carry-over ----------------------------------
    def _build(self, grasp: LeafGrasp | None, old_context) -> None:
        """Makes the station with ``grasp`` (None: no leaf held) current and
        carries ``old_context``'s state over. The station without a grasp is
        built once and kept: a release goes back to it (its leaves all
        enabled, as in a new Context) instead of building it again (1-1.5 s
        a release with four FEM leaves)."""
        self._frozen = {}
        self._fruit_id_set = None
        if grasp is None and self._free is not None:
            self.diagram, self.station, self.simulator = self._free
        else:
            if self._make_diagram is None:
                self.station = MakePlantStation(self.scenario, self.meshcat, leaf_grasp=grasp)
                self.diagram = self.station
            else:
                self.diagram, self.station = self._make_diagram(self.scenario, self.meshcat,
                                                                grasp)
            self.simulator = Simulator(self.diagram)
            self.simulator.set_target_realtime_rate(0.0)
            if grasp is None:
                self._free = (self.diagram, self.station, self.simulator)
        self.context = self.simulator.get_mutable_context()
        if old_context is not None and old_context is not self.context:
            self._CopyState(old_context, self.context)
        self.plant = self.station.GetSubsystemByName("plant")
        self.scene_graph = self.station.GetSubsystemByName("scene_graph")
        SetFemThreads(self.plant, self.scenario.plant_scene.fem_threads)
        self.deformable = self.plant.deformable_model()
        from lmap_drake.plants.scene import LeafBodyName
        n_leaves = len(self.leaf_refs) if self.multi else 1
        self.leaf_ids = [self.deformable.GetBodyByName(LeafBodyName(self.multi, j)).body_id()
                         for j in range(n_leaves)]
        self.leaf_id = self.leaf_ids[0]
        plant_context = self.plant.GetMyMutableContextFromRoot(self.context)
        for lid in self.leaf_ids:        # a kept station's leaves may have been asleep
            if not self.deformable.is_enabled(lid, plant_context):
                self.deformable.Enable(lid, plant_context)
        self.ApplyCommands()
        self.simulator.Initialize()

    @staticmethod
    def _CopyState(src, dst) -> None:
        """Copies time and every discrete/abstract state group (the two
        stations differ only by a constraint, so their layouts match)."""
        if (src.num_discrete_state_groups() != dst.num_discrete_state_groups()
                or src.num_abstract_states() != dst.num_abstract_states()
                or src.num_continuous_states() or dst.num_continuous_states()):
            # (continuous state would not be carried over: none today, the
            # plant and the command interpolator are discrete)
            raise RuntimeError("station state layouts differ; cannot carry the state over")
        dst.SetTime(src.get_time())
        for i in range(src.num_discrete_state_groups()):
            dst.SetDiscreteState(i, src.get_discrete_state(i).value())
        for i in range(src.num_abstract_states()):
            dst.get_mutable_abstract_state(i).SetFrom(src.get_abstract_state(i))

    @property
    def drives_ports(self) -> bool:
        """True when this object commands the station (no controller)."""
        return self.diagram is self.station

    def ApplyCommands(self) -> None:
        """Sets the station's inputs to ``q_cmd`` and ``width_cmd`` (when
        this object commands the station)."""
        if self.drives_ports:
            self.station.GetInputPort("ur5.position").FixValue(self.context, self.q_cmd)
            self.station.GetInputPort("gripper.position").FixValue(self.context,
                                                                   [self.width_cmd])

    @property
    def station_context(self):
        return self.station.GetMyContextFromRoot(self.context)

    @property
    def plant_context(self):
        return self.plant.GetMyContextFromRoot(self.context)

    @property
    def time(self) -> float:
        return self.context.get_time()

    # --- reading the world ------------------------------------------------
    def LeafVertices(self, leaf: int = 0) -> np.ndarray:
        """Current vertex positions (N, 3), world frame, of leaf ``leaf`` (the
        only one of a procedural plant)."""
        return self.deformable.GetPositions(self.plant_context, self.leaf_ids[leaf]).T.copy()

    def q(self) -> np.ndarray:
        return self.station.GetOutputPort("ur5.position_measured").Eval(self.station_context).copy()

    def GripperWidth(self) -> float:
        return float(self.station.GetOutputPort("gripper.state_measured").Eval(self.station_context)[0])

    def X_WG(self) -> RigidTransform:
        """Current pose of the gripper base (robotiq_base) in the world."""
        return self.plant.CalcRelativeTransform(
            self.plant_context, self.plant.world_frame(), self.plant.GetFrameByName("robotiq_base"))

    def X_WT(self) -> RigidTransform:
        return self.plant.CalcRelativeTransform(
            self.plant_context, self.plant.world_frame(), self.plant.GetFrameByName("tcp"))

    def Images(self) -> dict:
        """Copies of camera0's current images (Eval returns cache entries
        that later evaluations overwrite)."""
        out = {}
        for name in ("rgb_image", "depth_image", "label_image"):
            image = self.station.GetOutputPort(f"camera0.{name}").Eval(self.station_context)
            copy_ = type(image)(image.width(), image.height())
            copy_.mutable_data[:] = image.data
            out[name] = copy_
        return out

    def Visibility(self, label=None, fruit: int | None = None) -> float:
        """The fruit's visible fraction in camera0 now, or in ``label`` (a
        label image or array, e.g. a captured view's). ``kind: multi``:
        fruit instance ``fruit`` (default 0)."""
        if label is None:
            label = self.station.GetOutputPort("camera0.label_image").Eval(self.station_context)
        return self.VisibilityUnion([label], fruit)

    def VisibilityUnion(self, labels: list, fruit: int | None = None) -> float:
        """The fraction of the fruit's unoccluded camera0 pixels that show
        it in at least one of ``labels`` (label images or arrays of the fixed
        camera0, e.g. an episode's captured views): what the fused views
        observed of it, over several views. ``kind: multi``: fruit instance
        ``fruit`` (default 0)."""
        if self.multi and fruit is None:
            fruit = 0
        if fruit not in self._unoccluded:
            self._unoccluded[fruit] = UnoccludedFruitPixels(self.scenario, fruit)
        return VisibilityFraction(labels, self._unoccluded[fruit], fruit)

    def Sample(self) -> OutcomeSample:
        """Ground-truth measures now (see ``OutcomeConfig``). A frozen leaf
        (asleep) keeps the measures taken when it fell asleep."""
        cfg = self.scenario.plant_scene
        strain = force = pen = 0.0
        ctx = self.plant_context
        fresh: dict[int, np.ndarray] = {}      # leaf -> vertices, for the leaves measured now
        measured: dict[int, tuple] = {}        # leaf -> (strain, force, asleep)
        loads: dict[int, tuple] = {}           # leaf -> (strain, force, robot contact N)
        touch = RobotLeafContactForces(
            self.plant.get_contact_results_output_port().Eval(ctx),
            self.scene_graph.model_inspector(),
            [self.deformable.GetGeometryId(lid) for lid in self.leaf_ids])
        for j, ref in enumerate(self.leaf_refs):
            asleep = not self.deformable.is_enabled(self.leaf_ids[j], ctx)
            if asleep and j in self._asleep_measures:     # frozen: as last measured
                s_j, f_j, p_j = self._asleep_measures[j]
                strain, force, pen = max(strain, s_j), max(force, f_j), max(pen, p_j)
                loads[j] = (s_j, f_j, touch.get(j, 0.0))
                continue
            V = fresh[j] = self.LeafVertices(j)
            constrained = np.flatnonzero(ref.fixed)
            if self.grasp_state is not None and self.grasp_state.grasp.leaf == j:
                constrained = np.union1d(constrained, self.grasp_state.vertices)
            if self._Dm_inv_of[j] is None:
                self._Dm_inv_of[j] = RestShapeInverse(ref.rest_W, ref.tets)
            stretch = MaxPrincipalStretch(ref.rest_W, V, ref.tets, self._Dm_inv_of[j])
            s_j = StrainPercentile(ref.rest_W, V, ref.tets,
                                   ConstrainedTetMask(ref.tets, constrained),
                                   cfg.outcome.strain_percentile, stretch)
            f_j = PetioleForce(ref.rest_W, V, ref.tets, self._petiole_tets_of[j],
                               cfg.leaf.youngs_modulus,
                               cfg.leaf.petiole_width * cfg.leaf.thickness, stretch)
            strain, force = max(strain, s_j), max(force, f_j)
            measured[j] = (s_j, f_j, asleep)
            loads[j] = (s_j, f_j, touch.get(j, 0.0))
        if fresh:
            leaves = list(fresh)
            allV = np.vstack([fresh[j] for j in leaves])
            # Only a vertex inside a fruit's box can be inside the fruit: the
            # others need no signed distance (they count as outside).
            fruit_meshes = ([f.mesh_W for f in self.model.fruits] if self.multi
                            else [self.model.fruit_mesh_W])
            inside = np.zeros(len(allV), bool)
            for m in fruit_meshes:
                lo, hi = np.asarray(m.bounds, float)
                inside |= np.all((allV >= lo - 1e-6) & (allV <= hi + 1e-6), axis=1)
            d = np.full(len(allV), np.inf)
            if inside.any() and self.multi:    # one ray-casting scene of every fruit
                if getattr(self, "_fruits_sdf", None) is None:
                    from lmap_drake.plants.multi_geometry import RaycastScene
                    self._fruits_sdf = RaycastScene(fruit_meshes)
                import open3d as o3d
                d[inside] = self._fruits_sdf.compute_signed_distance(
                    o3d.core.Tensor(allV[inside].astype(np.float32)),
                    nsamples=SIGN_RAYS).numpy()
            elif inside.any():
                d[inside] = MeshSignedDistance(fruit_meshes[0], allV[inside])
            ends = np.cumsum([len(fresh[j]) for j in leaves])
            for j, part in zip(leaves, np.split(np.asarray(d, float), ends[:-1])):
                p_j = max(0.0, -float(part.min()))
                pen = max(pen, p_j)
                s_j, f_j, asleep = measured[j]
                if asleep:
                    self._asleep_measures[j] = (s_j, f_j, p_j)
                else:
                    self._asleep_measures.pop(j, None)
        pen = max(pen, self._RobotFruitPenetration())
        held = self.grasp_state.grasp.leaf if self.grasp_state is not None else None
        return OutcomeSample(strain, force, pen, self._FruitContactForce(),
                             self._RobotContactForce(), t=self.time, leaf_loads=loads,
                             grasped_leaf=held)

    def _fruit_ids(self) -> set:
        """The fruits' collision geometries (of the current Diagram)."""
        if self._fruit_id_set is None:
            inspector = self.scene_graph.model_inspector()
            self._fruit_id_set = {g for g in inspector.GetAllGeometryIds()
                                  if inspector.GetName(g).endswith("_collision")
                                  and inspector.GetName(g).split("::")[-1].startswith("fruit")}
        return self._fruit_id_set

    def _RobotFruitPenetration(self) -> float:
        query = self.scene_graph.get_query_output_port().Eval(
            self.scene_graph.GetMyContextFromRoot(self.context))
        fruit = self._fruit_ids()
        inspector = query.inspector()
        worst = 0.0
        for pair in query.ComputeSignedDistancePairwiseClosestPoints(max_distance=0.005):
            ids = {pair.id_A, pair.id_B}
            if ids & fruit and pair.distance < 0:
                other = (ids - fruit).pop()
                frame = inspector.GetFrameId(other)
                body = self.plant.GetBodyFromFrameId(frame)
                if body is not None and body.name() != "branch":
                    worst = max(worst, -pair.distance)
        return worst

    def _FruitContactForce(self) -> float:
        results = self.plant.get_contact_results_output_port().Eval(self.plant_context)
        fruit = self._fruit_ids()
        total = 0.0
        for i in range(results.num_deformable_contacts()):
            info = results.deformable_contact_info(i)
            if {info.id_A(), info.id_B()} & fruit:
                total += float(np.linalg.norm(info.F_Ac_W().translational()))
        for i in range(results.num_point_pair_contacts()):
            info = results.point_pair_contact_info(i)
            ids = {info.point_pair().id_A, info.point_pair().id_B}
            if ids & fruit:
                total += float(np.linalg.norm(info.contact_force()))
        for i in range(results.num_hydroelastic_contacts()):
            info = results.hydroelastic_contact_info(i)
            ids = {info.contact_surface().id_M(), info.contact_surface().id_N()}
            if ids & fruit:
                total += float(np.linalg.norm(info.F_Ac_W().translational()))
        return total

    def _RobotContactForce(self) -> float:
        """Largest rigid contact force (N) of the arm or gripper on itself or
        on a branch (a planned motion should have neither)."""
        results = self.plant.get_contact_results_output_port().Eval(self.plant_context)
        inspector = self.scene_graph.model_inspector()

        def kind(gid) -> str:
            name = inspector.GetName(gid)
            if name.startswith(("ur5::", "robotiq_2f85::")):
                return "robot"
            return "branch" if "branch" in name.split("::")[-1] else ""
        worst = 0.0
        pairs = []
        for i in range(results.num_point_pair_contacts()):
            info = results.point_pair_contact_info(i)
            pairs.append((info.point_pair().id_A, info.point_pair().id_B,
                          np.linalg.norm(info.contact_force())))
        for i in range(results.num_hydroelastic_contacts()):
            info = results.hydroelastic_contact_info(i)
            pairs.append((info.contact_surface().id_M(), info.contact_surface().id_N(),
                          np.linalg.norm(info.F_Ac_W().translational())))
        for a, b, f in pairs:
            kinds = {kind(a), kind(b)}
            if kinds in ({"robot"}, {"robot", "branch"}):
                worst = max(worst, float(f))
                if f > self.worst_robot_contact["force_N"]:
                    self.worst_robot_contact = {
                        "force_N": float(f), "t": round(self.time, 3),
                        "pair": f"{inspector.GetName(a)} / {inspector.GetName(b)}"}
        return worst

    # --- acting -----------------------------------------------------------
    def AdvanceTo(self, t: float, q_traj: PiecewisePolynomial | None = None,
                  step: float = 0.01, sample: bool = True) -> None:
        """Simulates to time ``t``, streaming ``q_traj`` (if given) as the joint
        command every ``step`` s and sampling the monitors (from the first
        step on, every ``outcome.sample_period``; ``sample=False``: none, the
        caller samples)."""
        period = self.scenario.plant_scene.outcome.sample_period
        next_sample = self.time
        while self.time < t - 1e-9:
            t_next = min(t, self.time + step)
            if q_traj is not None:
                if not self.drives_ports:
                    raise RuntimeError("a controller drives this diagram; no q_traj")
                self.q_cmd = q_traj.value(t_next).ravel()
                self.station.GetInputPort("ur5.position").FixValue(self.context, self.q_cmd)
            self.simulator.AdvanceTo(t_next)
            self._UpdateSleep()
            if sample and self.time >= next_sample - 1e-9:
                self.samples.append(self.Sample())
                next_sample = self.time + period

    def _UpdateSleep(self) -> None:
        """Freezes the leaves at rest far from the robot and wakes the ones
        it comes near or holds (``plant_scene.sleep_distance``)."""
        cfg = self.scenario.plant_scene
        d_max = cfg.sleep_distance
        if d_max <= 0 or (self.multi and cfg.multi.leaf_leaf_contact):
            return
        ctx = self.plant.GetMyMutableContextFromRoot(self.context)
        bodies = None
        for j, lid in enumerate(self.leaf_ids):
            enabled = self.deformable.is_enabled(lid, ctx)
            if self.grasp_state is not None and self.grasp_state.grasp.leaf == j:
                if not enabled:
                    self._Wake(j, lid, ctx)
                continue
            if enabled and np.abs(self.deformable.GetVelocities(ctx, lid)).max() >= \
                    cfg.sleep_speed:
                continue        # still moving: stays awake
            if bodies is None:
                bodies = self.robot.SurfacePointsByBody(self.q(), 0.5 * self.GripperWidth())
            if enabled:
                leaf = LeafProximity(self.LeafVertices(j))
            else:       # frozen: its vertices do not change until it wakes
                leaf = self._frozen.get(j)
                if leaf is None:
                    leaf = self._frozen[j] = LeafProximity(self.LeafVertices(j))
            near = leaf.Near(bodies, d_max)
            if enabled and not near:
                self.deformable.Disable(lid, ctx)
            elif not enabled and near:
                self._Wake(j, lid, ctx)

    def _Wake(self, j: int, lid, ctx) -> None:
        self.deformable.Enable(lid, ctx)
        self._frozen.pop(j, None)

    def Hold(self, duration: float) -> None:
        self.AdvanceTo(self.time + duration)

    def MoveJoints(self, waypoints: list[np.ndarray], speed_fraction: float = 0.5) -> None:
        """Joint-space motion through ``waypoints`` from the current command
        (see ``planning.motion.TimeJointPath``)."""
        from lmap_drake.planning.motion import TimeJointPath
        traj = TimeJointPath(self.time, self.q_cmd, waypoints, speed_fraction)
        self.AdvanceTo(traj.end_time(), traj)

    def SetGripper(self, width: float, duration: float = 0.6) -> None:
        self.width_cmd = float(np.clip(width, 0.0, GRIPPER_MAX_WIDTH))
        self.station.GetInputPort("gripper.position").FixValue(self.context, [self.width_cmd])
        self.Hold(duration)

    def CloseOnLeaf(self, timeout: float = 1.0) -> float:
        """Closes the pads toward the leaf's thickness and stops as soon as
        they have closed on it (opening within 1.5 mm of the thickness) or
        stalled; returns the opening (m)."""
        thickness = self.scenario.plant_scene.leaf.thickness
        self.width_cmd = max(0.0, thickness - 0.0005)
        self.station.GetInputPort("gripper.position").FixValue(self.context, [self.width_cmd])
        t_end, last = self.time + timeout, self.GripperWidth()
        while self.time < t_end:
            self.Hold(0.02)
            width = self.GripperWidth()
            if width <= thickness + 0.0015 or abs(width - last) < 1e-5:
                break
            last = width
        return self.GripperWidth()

    def Grasp(self) -> GraspState:
        """Rebuilds the station with the leaf region between the pads fixed to
        the gripper (see the module docstring). Raises if no leaf vertex lies
        between the pads."""
        width = self.GripperWidth()
        X_WG = self.X_WG()
        X_GT = X_WG.inverse() @ self.X_WT()
        pad = np.array([0.022, max(width, 0.001) + 0.004, 0.038])
        best = (np.zeros(0, int), 0, None)
        for j in range(len(self.leaf_refs)):     # the leaf with most vertices between the pads
            V = self.LeafVertices(j)
            p_G = (X_WG.inverse().GetAsMatrix4() @ np.c_[V, np.ones(len(V))].T).T[:, :3]
            rel = np.abs(p_G - X_GT.translation())
            inside = np.flatnonzero(np.all(rel <= pad / 2, axis=1))
            if len(inside) > len(best[0]):
                best = (inside, j, V)
        inside, leaf, V = best
        if len(inside) < 3:
            static = self._StaticLeafBetweenPads(X_WG, X_GT, pad)
            why = "" if static is None else (
                f"; the pads hold leaf {static}, which this simulated plant models as static "
                f"(welded, not FEM: plant_scene.greenhouse.max_fem_leaves, fem_occluders)")
            raise RuntimeError(f"grasp failed: {len(inside)} leaf vertices between the pads "
                               f"(opening {width * 1000:.1f} mm){why}")
        T = _Kabsch(self.leaf_refs[leaf].rest_W[inside], V[inside])
        grasp = LeafGrasp(X_GA=X_WG.inverse() @ T, p_GR=X_GT.translation(), size=pad,
                          leaf=leaf)
        old_simulator = self.simulator  # keep the old context alive while copying
        self._build(grasp, self.context)
        del old_simulator
        self.grasp_state = GraspState(grasp, inside)
        self.progress(f"grasped {len(inside)} leaf vertices" + (f" (leaf {leaf})" if self.multi else ""))
        return self.grasp_state

    def _StaticLeafBetweenPads(self, X_WG, X_GT, pad) -> int | None:
        """The index (FEM leaves first) of a static leaf of a greenhouse or
        mesh plant with surface vertices between the pads, or None."""
        statics = getattr(self.model, "static_leaves", None) or []
        X_GW = X_WG.inverse().GetAsMatrix4()
        for s, leaf in enumerate(statics):
            V = np.asarray(leaf.surface_W.vertices, float)
            p_G = (X_GW @ np.c_[V, np.ones(len(V))].T).T[:, :3]
            if np.any(np.all(np.abs(p_G - X_GT.translation()) <= pad / 2, axis=1)):
                return len(self.leaf_refs) + s
        return None

    def Fork(self) -> "PlantWorldSim":
        """An independent copy that continues from the current state (same
        Diagram, cloned Context), e.g. to try several pulls from one grasp."""
        other = copy.copy(self)
        other._free = None          # its own station without a grasp, when it releases
        other.context = self.context.Clone()
        other.simulator = Simulator(self.diagram, other.context)
        other.simulator.set_target_realtime_rate(0.0)
        other.samples = list(self.samples)
        other._asleep_measures = dict(self._asleep_measures)
        other._frozen = dict(self._frozen)
        other.worst_robot_contact = dict(self.worst_robot_contact)
        other.q_cmd = self.q_cmd.copy()
        other.simulator.Initialize()
        return other

    def Release(self) -> None:
        old_simulator, old_context = self.simulator, self.context
        self._build(None, old_context)
        del old_simulator
        self.grasp_state = None
