"""Drake contact of FEM leaves (the leaves of a ``kind: multi`` plant):
a leaf dropped on a fruit rests on it; Drake 1.51's deformable-deformable
contact does not keep a leaf dropped on another from passing through it
(a canary test: see its docstring). Small leaves and short horizons keep these cheap."""
import numpy as np
from pydrake.geometry import CollisionFilterDeclaration, GeometrySet
from pydrake.math import RigidTransform
from pydrake.multibody.plant import (AddMultibodyPlant, CoulombFriction,
                                     MultibodyPlantConfig)
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from lmap_drake.labels import LEAF, EncodeLabel
from lmap_drake.plants.generator import MeshSignedDistance
from lmap_drake.plants.leaf import ExtrudeToTets, LeafShape, OrientTets, TriangulateLeaf
from lmap_drake.plants.pepper import MakePepper, PepperShapeOf
from lmap_drake.plants.scene import AddFemLeaf, _ObjMesh
from lmap_drake.plants.config import FruitConfig, LeafConfig

THICKNESS = 0.002


def _flat_leaf(z: float, dx: float = 0.0, dy: float = 0.0, scale: float = 1.0):
    """A small horizontal leaf (rest vertices, tets), midrib along +x."""
    shape = LeafShape(length=0.08 * scale, width=0.05 * scale, petiole_length=0.02,
                      thickness=THICKNESS, element_size=0.009 * scale)
    uv, faces = TriangulateLeaf(shape)
    nodes, tets = ExtrudeToTets(uv, faces, layers=2)
    V = np.c_[nodes[:, 0] - 0.04 + dx, nodes[:, 1] + dy, z + (nodes[:, 2] - 1) * THICKNESS / 2]
    return V, OrientTets(V, tets)


def _world(leaves, fruit=None, leaf_leaf_contact=True, table_top=None):
    """Plant with the given leaves ((V, tets, fixed mask) each), an optional
    fruit mesh welded to the world and an optional rigid table (top at z
    ``table_top``)."""
    from pydrake.geometry import Box
    builder = DiagramBuilder()
    plant, sg = AddMultibodyPlant(MultibodyPlantConfig(
        time_step=0.01, discrete_contact_approximation="sap"), builder)
    if table_top is not None:
        plant.RegisterCollisionGeometry(plant.world_body(), RigidTransform([0, 0, table_top - 0.05]),
                                        Box(0.3, 0.3, 0.1), "table", CoulombFriction(0.8, 0.8))
    if fruit is not None:
        plant.RegisterCollisionGeometry(plant.world_body(), RigidTransform(),
                                        _ObjMesh(fruit, "fruit"), "fruit_collision",
                                        CoulombFriction(0.5, 0.5))
    ids, gids = [], []
    for j, (V, T, fixed) in enumerate(leaves):
        bid, gid = AddFemLeaf(plant, f"leaf_{j}", V, T, fixed, LeafConfig(),
                              EncodeLabel(LEAF, j))
        ids.append(bid)
        gids.append(gid)
    if not leaf_leaf_contact:
        sg.collision_filter_manager().Apply(
            CollisionFilterDeclaration().ExcludeWithin(GeometrySet(gids)))
    plant.Finalize()
    diagram = builder.Build()
    sim = Simulator(diagram)
    ctx = plant.GetMyContextFromRoot(sim.get_mutable_context())

    def positions(j):
        return plant.deformable_model().GetPositions(ctx, ids[j]).T.copy()
    return sim, positions


def test_leaf_dropped_on_a_fruit_rests_on_it():
    fruit = MakePepper(PepperShapeOf(FruitConfig())).mesh
    fruit.apply_translation([0.0, 0.0, 0.2])
    top = float(fruit.vertices[:, 2].max())
    V, T = _flat_leaf(top + THICKNESS / 2 + 0.002)
    sim, positions = _world([(V, T, np.zeros(len(V), bool))], fruit=fruit)
    above = np.linalg.norm(V[:, :2], axis=1) < 0.012     # over the fruit's top
    pen = []
    for t in np.arange(0.02, 0.301, 0.02):
        sim.AdvanceTo(t)
        pen.append(-float(MeshSignedDistance(fruit, positions(0)).min()))
    # Measured: up to 3 mm into the stem cavity at the impact (2 mm drop),
    # then pushed out; at rest < 0.05 mm.
    assert max(pen) < 0.004, f"leaf entered the fruit by {max(pen) * 1e3:.2f} mm"
    assert pen[-1] < 0.0005, f"leaf rests {pen[-1] * 1e3:.2f} mm inside the fruit"
    # Still lying on the top (free fall would have taken it 0.44 m down).
    assert positions(0)[above, 2].min() > top - 0.001


def _depth_below_top(A: np.ndarray, top: np.ndarray, P: np.ndarray) -> np.ndarray:
    """How far (m) each point of P lies below leaf A's upper surface (its
    ``top`` vertices, linearly interpolated over x-y); NaN off A."""
    from scipy.interpolate import LinearNDInterpolator
    return LinearNDInterpolator(A[top, :2], A[top, 2])(P[:, :2]) - P[:, 2]


def test_drake_leaf_leaf_contact_does_not_keep_thin_leaves_apart():
    """A canary for a Drake limitation (1.51.1): leaf A lies free on a rigid
    table, leaf B is dropped on it from 0.5 mm with deformable-deformable
    contact on. Contact is computed (it slows B) but B ends up through A
    (measured at 0.2 s: B's underside 2.6-2.9 mm below A's top, A 2 mm
    thick, A pushed up). With A held by a fixed constraint instead, B sinks
    through it in ~0.5 s; at time_step 0.002 SAP fails to converge. Hence
    ``multi.leaf_leaf_contact`` defaults to false and the generator keeps
    leaves apart at rest. If this test fails, Drake now holds thin leaves
    apart: revisit that default."""
    z0 = 0.3
    A, TA = _flat_leaf(z0, dx=-0.01, scale=1.5)                 # larger
    B, TB = _flat_leaf(z0 + THICKNESS + 0.0005, dy=0.003)       # on A's middle
    sim, positions = _world([(A, TA, np.zeros(len(A), bool)),
                             (B, TB, np.zeros(len(B), bool))], leaf_leaf_contact=True,
                            table_top=z0 - THICKNESS / 2 - 0.0003)
    bottom = np.isclose(B[:, 2], B[:, 2].min()) & (B[:, 0] > -0.035)   # B's blade underside
    top_A = np.isclose(A[:, 2], A[:, 2].max())
    sim.AdvanceTo(0.2)
    depth = _depth_below_top(positions(0), top_A, positions(1)[bottom])
    depth = depth[np.isfinite(depth)]
    assert len(depth) > 0.5 * bottom.sum()
    assert np.median(depth) > THICKNESS, \
        f"B's underside is only {np.median(depth) * 1e3:.2f} mm below A's top: Drake now " \
        f"keeps thin leaves apart"
