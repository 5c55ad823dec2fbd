"""The planner's robot: the UR5 + 2F-85 controller MultibodyPlant (with its
SceneGraph) used for IK, forward kinematics, self-collision queries and
surface samples of the robot's collision geometry (for SDF collision checks
and visibility)."""
from __future__ import annotations

import numpy as np
from pydrake.geometry import Box, Capsule, Cylinder, Role
from pydrake.math import RigidTransform
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
from pydrake.multibody.tree import JointIndex
from pydrake.systems.framework import DiagramBuilder

from lmap_drake.planning.ik import (IkResult, NewtonTcpIk, SolveTcpIk,
                                   SolveTcpIkMultiStart)
from lmap_drake.robot import AddUr5AndGripper


# Clearance (m) kept between arm links three or more joints apart along the
# approach and retreat (``RobotModel.SelfCollision``).
SELF_MARGIN = 0.01


def _SampleShape(shape, spacing: float) -> np.ndarray:
    """Surface points (N, 3) of a Drake shape in its own frame."""
    if isinstance(shape, Box):
        ext = np.array([shape.width(), shape.depth(), shape.height()]) / 2
        pts = []
        for axis in range(3):
            others = [a for a in range(3) if a != axis]
            g = [np.linspace(-ext[a], ext[a], max(2, int(np.ceil(2 * ext[a] / spacing)) + 1))
                 for a in others]
            u, v = np.meshgrid(*g, indexing="ij")
            for sign in (-1, 1):
                p = np.zeros((u.size, 3))
                p[:, others[0]], p[:, others[1]] = u.ravel(), v.ravel()
                p[:, axis] = sign * ext[axis]
                pts.append(p)
        return np.vstack(pts)
    r = shape.radius()
    length = shape.length()
    n_ring = max(8, int(np.ceil(2 * np.pi * r / spacing)))
    th = np.linspace(0, 2 * np.pi, n_ring, endpoint=False)
    zs = np.linspace(-length / 2, length / 2, max(2, int(np.ceil(length / spacing)) + 1))
    side = np.stack([np.repeat(np.cos(th)[None], len(zs), 0) * r,
                     np.repeat(np.sin(th)[None], len(zs), 0) * r,
                     np.repeat(zs[:, None], n_ring, 1)], -1).reshape(-1, 3)
    if isinstance(shape, Capsule):
        phis = np.linspace(0, np.pi / 2, max(2, int(np.ceil(np.pi / 2 * r / spacing))))
        caps = []
        for sign in (-1, 1):
            for phi in phis:
                rr = r * np.cos(phi)
                k = max(1, int(np.ceil(2 * np.pi * rr / spacing)))
                t = np.linspace(0, 2 * np.pi, k, endpoint=False)
                caps.append(np.c_[rr * np.cos(t), rr * np.sin(t),
                                  np.full(k, sign * (length / 2 + r * np.sin(phi)))])
        return np.vstack([side] + caps)
    # cylinder: add end discs
    discs = []
    for sign in (-1, 1):
        for rr in np.arange(0, r, spacing):
            k = max(1, int(np.ceil(2 * np.pi * rr / spacing)))
            t = np.linspace(0, 2 * np.pi, k, endpoint=False)
            discs.append(np.c_[rr * np.cos(t), rr * np.sin(t), np.full(k, sign * length / 2)])
    return np.vstack([side] + discs)


def _ShapeParams(shape) -> tuple:
    """(kind, dims) of a Drake Box, Capsule or Cylinder: 'box' with its
    half extents (3,), 'capsule' / 'cylinder' with (radius, half length)."""
    if isinstance(shape, Box):
        return "box", np.array([shape.width(), shape.depth(), shape.height()]) / 2
    kind = "capsule" if isinstance(shape, Capsule) else "cylinder"
    return kind, np.array([shape.radius(), shape.length() / 2])


def _LongAxis(kind: str, dims: np.ndarray) -> tuple[int, float, float]:
    """(axis index, half length along it, radius of the cross-section
    around it) of a shape of ``_ShapeParams`` in its own frame: every
    point of the shape lies within that radius of that segment."""
    if kind == "box":
        axis = int(np.argmax(dims))
        return axis, float(dims[axis]), float(np.linalg.norm(np.delete(dims, axis)))
    r, h = dims
    return 2, float(h + (r if kind == "capsule" else 0.0)), float(r)


def ShapeSignedDistance(kind: str, dims: np.ndarray, p_G: np.ndarray) -> np.ndarray:
    """Signed distance (m, negative inside) of points ``p_G`` (N, 3, in the
    shape's own frame, Drake's conventions: a box centred, capsules and
    cylinders along z) to a shape of ``_ShapeParams``."""
    p = np.asarray(p_G, float).reshape(-1, 3)
    if kind == "box":
        d = np.abs(p) - dims
        return (np.linalg.norm(np.maximum(d, 0.0), axis=1) + np.minimum(d.max(axis=1), 0.0))
    r, h = dims
    if kind == "capsule":
        axis = np.c_[np.zeros((len(p), 2)), np.clip(p[:, 2], -h, h)]
        return np.linalg.norm(p - axis, axis=1) - r
    d = np.c_[np.linalg.norm(p[:, :2], axis=1) - r, np.abs(p[:, 2]) - h]
    return np.linalg.norm(np.maximum(d, 0.0), axis=1) + np.minimum(d.max(axis=1), 0.0)


class SurfaceSamples:
    """The robot's surface samples at one pose, per geometry (see
    ``RobotModel.SurfacePointsByBody``): ``samples[i]`` (N_i, 3, world) is
    computed when first read; ``boxes`` (G, 2, 3) at once from 8 corners
    per geometry, ``corners`` (G, 8, 3) those corners in the world.
    ``shapes``: per geometry (kind, dims, X_BG 4x4) for ``SignedDistance``."""

    def __init__(self, local: list, corners: list, X: list, fingers: np.ndarray | None = None,
                 shapes: list | None = None):
        self._local, self._X, self._shapes = local, X, shapes
        # which geometries are on the two fingers (pads and links)
        self.fingers = (np.zeros(len(local), bool) if fingers is None
                        else np.asarray(fingers, bool))
        self._world: dict[int, np.ndarray] = {}
        # every geometry at once (the same products as one geometry at a time)
        Xs = np.asarray(X, float).reshape(-1, 4, 4)
        w = np.matmul(np.asarray(corners, float).reshape(-1, 8, 3),
                      Xs[:, :3, :3].transpose(0, 2, 1)) + Xs[:, None, :3, 3]
        self.corners = w
        self.boxes = np.stack([w.min(axis=1), w.max(axis=1)], axis=1)

    def __len__(self) -> int:
        return len(self._local)

    def SignedDistance(self, points_W: np.ndarray, reach: float, tree=None) -> np.ndarray:
        """Signed distance (m, negative inside) of ``points_W`` (N, 3) to the
        robot's collision geometry at this pose, exact where it is below
        ``reach`` (m); points farther than ``reach`` from every geometry's
        box get ``inf``. ``tree``: a ``cKDTree`` of ``points_W`` to find
        each geometry's neighbours by (else every point is tested against
        each box). Needs ``shapes``."""
        p = np.asarray(points_W, float).reshape(-1, 3)
        out = np.full(len(p), np.inf)
        if not len(p):
            return out
        # the points' box (a tree of them holds it) against every geometry's
        # box grown by ``reach``, at once
        p_lo, p_hi = ((tree.mins, tree.maxes) if tree is not None and tree.n == len(p)
                      else (p.min(axis=0), p.max(axis=0)))
        lo, hi = self.boxes[:, 0] - reach, self.boxes[:, 1] + reach
        meets = np.flatnonzero(~np.any(p_lo > hi, axis=1) & ~np.any(p_hi < lo, axis=1))
        X_WG = {int(i): self._X[i] @ self._shapes[i][2] for i in meets}
        found = {}
        if tree is not None and len(meets):     # balls along each shape's long axis, one query
            centres, radii, spans = [], [], {}
            for i in X_WG:
                axis, half, r = _LongAxis(*self._shapes[i][:2])
                k = max(1, int(np.ceil(2 * half / max(r, 1e-3))))
                c = np.outer((np.arange(k) + 0.5) / k * 2 * half - half, X_WG[i][:3, axis])
                spans[i] = (sum(len(b) for b in centres), k)
                centres.append(c + X_WG[i][:3, 3])
                radii.append(np.full(k, np.hypot(r, half / k) + reach))
            balls = tree.query_ball_point(np.vstack(centres), np.concatenate(radii))
            for i, (start, k) in spans.items():
                found[i] = np.unique(np.concatenate([np.asarray(f, int)
                                                     for f in balls[start:start + k]]))
        for i in X_WG:
            kind, dims, _ = self._shapes[i]
            near = (found[i] if tree is not None else
                    np.flatnonzero(np.all((p >= lo[i]) & (p <= hi[i]), axis=1)))
            if not len(near):
                continue
            p_G = (p[near] - X_WG[i][:3, 3]) @ X_WG[i][:3, :3]
            out[near] = np.minimum(out[near], ShapeSignedDistance(kind, dims, p_G))
        return out

    def __getitem__(self, i: int) -> np.ndarray:
        if not 0 <= i < len(self._local):
            raise IndexError(i)
        if i not in self._world:
            X = self._X[i]
            self._world[i] = self._local[i] @ X[:3, :3].T + X[:3, 3]
        return self._world[i]


class RobotModel:
    """UR5 + gripper for planning. ``X_WB``: robot base in the world.
    Joint vectors ``q`` are the 6 UR5 angles (rad); the gripper half-opening
    is fixed per query (m)."""

    def __init__(self, X_WB: RigidTransform, spacing: float = 0.01,
                 gripper_spacing: float = 0.004):
        """Collision surfaces are sampled every ``spacing`` (m) on the arm and
        every ``gripper_spacing`` on the gripper (the part that comes close
        to the leaf and fruit)."""
        builder = DiagramBuilder()
        self.plant, self.scene_graph = AddMultibodyPlantSceneGraph(builder, 0.0)
        self.ur5, self.gripper = AddUr5AndGripper(self.plant, X_WB)
        self.plant.Finalize()
        self._diagram = builder.Build()
        self._diagram_context = self._diagram.CreateDefaultContext()
        self.context = self.plant.GetMyMutableContextFromRoot(self._diagram_context)
        self._ik_context = self.plant.CreateDefaultContext()
        self.tcp = self.plant.GetFrameByName("tcp")
        inspector = self.scene_graph.model_inspector()
        self._bodies, self._points, self._shapes = [], [], []
        for gid in inspector.GetAllGeometryIds(Role.kProximity):
            shape = inspector.GetShape(gid)
            if not isinstance(shape, (Box, Capsule, Cylinder)):
                continue
            body = self.plant.GetBodyFromFrameId(inspector.GetFrameId(gid))
            X_BG = inspector.GetPoseInFrame(gid)
            on_gripper = self.plant.GetModelInstanceName(body.model_instance()) == \
                self.plant.GetModelInstanceName(self.gripper)
            p = _SampleShape(shape, gripper_spacing if on_gripper else spacing)
            self._bodies.append(body)
            self._points.append((X_BG.GetAsMatrix4() @ np.c_[p, np.ones(len(p))].T).T[:, :3])
            self._shapes.append(_ShapeParams(shape) + (X_BG.GetAsMatrix4(),))
        self.num_points = int(sum(len(p) for p in self._points))
        self._gripper_samples: dict = {}    # GripperSamplesInTcp, per half-opening
        index = {b.index(): k for k, b in reversed(list(enumerate(self._bodies)))}
        self._unique_bodies = [self._bodies[k] for k in sorted(set(index.values()))]
        order = {b.index(): n for n, b in enumerate(self._unique_bodies)}
        self._body_of_geometry = [order[b.index()] for b in self._bodies]
        # the geometries on the two fingers (pads and finger links)
        self._fingers = np.array([b.name() in ("left_finger", "right_finger")
                                  for b in self._bodies], bool)
        # each geometry's sample box in its body frame, as 8 corners
        self._corners = np.array([[[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                                    for z in (lo[2], hi[2])]
                                   for lo, hi in ((p.min(axis=0), p.max(axis=0))
                                                  for p in self._points)]).reshape(-1, 8, 3)
        # Self-collision pairs worth reporting: the gripper's own parts touch
        # each other by design (pads closing on nothing), the rest is the
        # plant's filtering (bodies joined by a joint).
        self._gripper_geoms = {
            gid for gid in inspector.GetAllGeometryIds(Role.kProximity)
            if self.plant.GetBodyFromFrameId(inspector.GetFrameId(gid)).model_instance()
            == self.gripper}
        # Moving joints from the world to each body: links three or more
        # joints apart must keep ``self_margin`` from each other (closer ones,
        # e.g. the forearm and the wrist 2 housing, are close by design).
        parent = {}
        for j in range(self.plant.num_joints()):
            joint = self.plant.get_joint(JointIndex(j))
            parent[joint.child_body().index()] = (joint.parent_body().index(),
                                                  0 if joint.num_velocities() == 0 else 1)

        def depth(b):
            n = 0
            while b in parent:
                b, moving = parent[b]
                n += moving
            return n
        self._depth = {gid: depth(self.plant.GetBodyFromFrameId(inspector.GetFrameId(gid)).index())
                       for gid in inspector.GetAllGeometryIds(Role.kProximity)}

    def SetQ(self, q: np.ndarray, half_opening: float = 0.0) -> None:
        self.plant.SetPositions(self.context, np.r_[np.asarray(q, float),
                                                     half_opening, half_opening])

    def SurfacePoints(self, q: np.ndarray, half_opening: float = 0.0) -> np.ndarray:
        """Samples of the robot's collision surfaces at ``q`` (N, 3), world."""
        return np.vstack(list(self.SurfacePointsByBody(q, half_opening)))

    def SurfacePointsByBody(self, q: np.ndarray, half_opening: float = 0.0) -> "SurfaceSamples":
        """``SurfacePoints`` split by geometry: a sequence of (N_g, 3) world
        arrays, each transformed when first read, with ``boxes`` (G, 2, 3):
        a world box (min, max) around each (its body-frame box turned into
        the world: it may be larger than the samples' own)."""
        self.SetQ(q, half_opening)
        # each body's pose once (a body carries several geometries)
        X_body = [self.plant.EvalBodyPoseInWorld(self.context, body).GetAsMatrix4()
                  for body in self._unique_bodies]
        return SurfaceSamples(self._points, self._corners,
                              [X_body[i] for i in self._body_of_geometry], self._fingers,
                              self._shapes)

    def GripperSamplesInTcp(self, half_opening: float) -> tuple[np.ndarray, np.ndarray]:
        """(finger samples (N, 3), other samples (M, 3)) in the ``tcp``
        frame of the geometries that move rigidly with the TCP whatever the
        arm's joints (the gripper, and what else the TCP is fixed to), with
        the pads ``half_opening`` (m) apart: the fingers' and the rest's
        (kept per opening)."""
        cache = self._gripper_samples
        key = float(half_opening)
        if key not in cache:
            rel = []
            for q in (np.zeros(6), np.array([0.3, -1.1, 1.2, -0.5, 0.7, 0.4])):
                samples = self.SurfacePointsByBody(q, key)
                X_TW = self.TcpPose(q, key).inverse().GetAsMatrix4()
                rel.append([X_TW @ X for X in samples._X])
            rigid = [bool(np.allclose(a, b, rtol=0.0, atol=1e-12)) for a, b in zip(*rel)]
            parts = []
            for want in (True, False):
                idx = [i for i in range(len(rigid)) if rigid[i] and self._fingers[i] == want]
                parts.append(np.vstack([self._points[i] @ rel[0][i][:3, :3].T + rel[0][i][:3, 3]
                                        for i in idx]) if idx else np.zeros((0, 3)))
            cache[key] = tuple(parts)
        return cache[key]

    def SelfCollision(self, q: np.ndarray, half_opening: float = 0.0,
                      margin: float = 0.0) -> str:
        """'' if the arm and gripper at ``q`` do not interpenetrate and links
        three or more joints apart keep ``margin`` (m) from each other, else
        the first offending pair, e.g. 'ur5::forearm / robotiq_2f85::body'
        (the gripper's own parts against each other are not counted; bodies
        joined by a joint are filtered by the plant). The planner asks for
        ``SELF_MARGIN`` along the approach: its fast joint moves are checked
        at samples, and the arm's tracking error adds to the path between
        them (the upper arm met the wrist 2 housing between checked approach
        poses in the FEM world)."""
        self.SetQ(q, half_opening)
        query = self.scene_graph.get_query_output_port().Eval(
            self.scene_graph.GetMyContextFromRoot(self._diagram_context))
        inspector = query.inspector()
        for pair in query.ComputeSignedDistancePairwiseClosestPoints(max(margin, 0.0)):
            a, b = pair.id_A, pair.id_B
            if a in self._gripper_geoms and b in self._gripper_geoms:
                continue
            if pair.distance < 0.0 or (pair.distance < margin
                                       and abs(self._depth[a] - self._depth[b]) >= 3):
                return f"{inspector.GetName(a)} / {inspector.GetName(b)}"
        return ""

    def TcpPose(self, q: np.ndarray, half_opening: float = 0.0) -> RigidTransform:
        self.SetQ(q, half_opening)
        return self.plant.CalcRelativeTransform(self.context, self.plant.world_frame(),
                                                self.tcp)

    def Ik(self, X_WT: RigidTransform, q_seed: np.ndarray, half_opening: float = 0.0,
           multistart: bool = False) -> IkResult:
        """IK (joint limits) for the TCP at ``X_WT``, warm-started: Newton
        steps on the plant's kinematics from ``q_seed`` first (the planner's
        targets are a few cm from a solved pose), Drake's
        ``InverseKinematics`` program (with random restarts if
        ``multistart``) when they do not converge."""
        r = NewtonTcpIk(self.plant, self._ik_context, X_WT, q_seed, half_opening)
        if r.success:
            return r
        solve = SolveTcpIkMultiStart if multistart else SolveTcpIk
        return solve(self.plant, X_WT, q_seed, gripper_half_opening=half_opening)
