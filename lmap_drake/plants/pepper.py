"""Sweet-pepper-like watertight meshes (metres, canonical frame O: centroid
at the origin, peduncle along +z).

The pepper shape family used everywhere in the project (plant-world
scenarios, DeepSDF training, shape-completion benchmarks):

* ``PepperShape``: the parameters of one pepper (metres / dimensionless).
* ``SamplePepperShape(rng)``: a seeded random member of the family (three
  variants: ``blocky``, ``elongated``, ``conical``). Frozen: the suite's
  random scenes (``plants/suite.py``) and the synthetic shape benchmark draw
  from it, so its draws must not change.
* ``SampleWidePepperShape(rng)``: the wider family the shipped DeepSDF
  template is trained on (``FAMILY_VERSION`` "wide-1"): largest extent
  4-11 cm, near-round to elongated (height / width 0.75-2.1), stem
  cavities 0-45 % deep and up to ~11 deg off the axis, mild bends, and a
  curved peduncle of 1-8 cm leaving 0-60 deg off the axis.
* ``MakePeduncle(...)``: the curved, capped tube of a peduncle.
* ``MakePepper(shape)``: the mesh in the canonical frame plus the peduncle
  attachment point ``p_O_peduncle`` (on the surface, on the +z axis).
* ``MakePepperMesh(size, lobes, lobe_depth, subdivisions)``: the original
  call used by the station (unchanged output).

Every mesh is an icosphere displaced radially (star-shaped about the origin)
followed by an x-y scaling that depends only on z and a sideways bend
x += k z^2 (both bijections of R^3), so it is watertight and free of
self-intersections by construction. The new parameters (``cavity_*``,
``bend*``, ``peduncle_*``) default to values that reproduce the old
shapes exactly.
"""
from __future__ import annotations

import dataclasses as dc
import hashlib

import numpy as np
import trimesh

VARIANTS = ("blocky", "elongated", "conical")


@dc.dataclass
class PepperShape:
    """Parameters of one pepper in its canonical frame O (metres).

    ``size`` is the full extent (x, y, z) of the underlying superquadric
    before lobes and taper; ``squareness`` is its exponent (2 = ellipsoid,
    larger = boxier); ``lobes`` (3-4) furrows of relative depth
    ``lobe_depth`` rotated by ``lobe_phase`` (rad); ``shoulder`` flattens the
    top around the peduncle, ``taper`` narrows the blossom end radially and
    ``cone`` narrows the lower half in x-y (0 = none, 0.45 = strongly
    conical); ``asymmetry`` bulges one side (direction ``asymmetry_phase``);
    ``dimple`` sinks the top around the peduncle (relative depth of the
    cavity the peduncle sits in); ``lobe_bottom`` (0-1) carries the lobes
    down to the blossom end (bumps at the bottom). The last two default to
    0, which keeps ``MakePepperMesh``'s original shapes.

    Wider family (all default to the old shapes): the stem cavity
    (``dimple``) has angular half-width ``cavity_width`` (rad) and its
    centre is tilted ``cavity_offset`` (rad) off +z toward azimuth
    ``cavity_phase``; the peduncle then leaves from the cavity's bottom,
    off the axis. ``bend`` (1/m) bends the body sideways (x' = x + k z^2
    along azimuth ``bend_phase``). ``peduncle_length`` > 0 (m) adds a curved
    peduncle tube (``Pepper.peduncle``) of radius ``peduncle_radius`` whose
    end leaves the axis by ``peduncle_angle`` (rad) toward
    ``peduncle_azimuth``; it is not part of the fruit body (the DeepSDF
    template is of the body).
    """
    size: tuple[float, float, float] = (0.075, 0.075, 0.085)
    lobes: int = 4
    lobe_depth: float = 0.08
    variant: str = "blocky"
    squareness: float = 2.0
    shoulder: float = 0.12
    taper: float = 0.06
    cone: float = 0.0
    lobe_phase: float = 0.0
    asymmetry: float = 0.0
    asymmetry_phase: float = 0.0
    dimple: float = 0.0
    lobe_bottom: float = 0.0
    cavity_width: float = 0.3
    cavity_offset: float = 0.0
    cavity_phase: float = 0.0
    bend: float = 0.0
    bend_phase: float = 0.0
    peduncle_length: float = 0.0
    peduncle_angle: float = 0.0
    peduncle_azimuth: float = 0.0
    peduncle_radius: float = 0.004

    def validate(self) -> None:
        if self.lobes < 0 or not 0.0 <= self.lobe_depth < 0.5:
            raise ValueError("lobes must be >= 0 and lobe_depth in [0, 0.5)")
        if min(self.size) <= 0:
            raise ValueError(f"size must be positive, got {self.size}")
        if not 1.5 <= self.squareness <= 6.0:
            raise ValueError("squareness must be in [1.5, 6]")
        if not (0 <= self.shoulder < 0.5 and 0 <= self.taper < 0.5
                and 0 <= self.cone < 0.8 and 0 <= self.asymmetry < 0.3):
            raise ValueError("shoulder/taper in [0, 0.5), cone in [0, 0.8), "
                             "asymmetry in [0, 0.3)")
        if not (0 <= self.dimple <= 0.45 and 0 <= self.lobe_bottom <= 1):
            raise ValueError("dimple in [0, 0.45], lobe_bottom in [0, 1]")
        if not (0.1 <= self.cavity_width <= 0.8 and 0 <= self.cavity_offset <= 0.6):
            raise ValueError("cavity_width in [0.1, 0.8] rad, cavity_offset in [0, 0.6] rad")
        if not abs(self.bend) <= 8.0:
            raise ValueError("|bend| must be <= 8 1/m")
        if not (0 <= self.peduncle_length <= 0.1 and 0 <= self.peduncle_angle <= 1.2
                and 0.001 <= self.peduncle_radius <= 0.01):
            raise ValueError("peduncle_length in [0, 0.1] m, peduncle_angle in [0, 1.2] rad, "
                             "peduncle_radius in [0.001, 0.01] m")
        if self.variant not in VARIANTS:
            raise ValueError(f"variant must be one of {VARIANTS}")


@dc.dataclass
class Pepper:
    """A pepper mesh in its canonical frame O (m) and the peduncle
    attachment point on top (m, on the +z axis)."""
    mesh: trimesh.Trimesh
    p_O_peduncle: np.ndarray
    shape: PepperShape
    peduncle: trimesh.Trimesh | None = None      # curved stalk in O (peduncle_length > 0)
    p_O_peduncle_tip: np.ndarray | None = None   # its far end


def _radius(d: np.ndarray, s: PepperShape) -> np.ndarray:
    """Radial distance (m) of the surface along unit directions ``d``."""
    a, b, c = (0.5 * x for x in s.size)
    p = s.squareness
    r = (np.abs(d[:, 0] / a) ** p + np.abs(d[:, 1] / b) ** p
         + np.abs(d[:, 2] / c) ** p) ** (-1.0 / p)
    phi = np.arctan2(d[:, 1], d[:, 0])
    equator = 1.0 - d[:, 2] ** 2
    lobe_w = equator
    if s.lobe_bottom > 0:  # fuller lobes in the lower half, down to the bottom
        low = d[:, 2] < 0
        lobe_w = np.where(low, np.clip(equator, 0, 1) ** (1.0 - 0.8 * s.lobe_bottom), equator)
    r = r * (1.0 - s.lobe_depth * 0.5 * (1.0 - np.cos(s.lobes * (phi - s.lobe_phase)))
             * lobe_w)
    # Shoulders near the peduncle are flatter, the blossom end tapered.
    r = r * (1.0 - s.shoulder * np.clip(d[:, 2], 0, 1) ** 6
             - s.taper * np.clip(-d[:, 2], 0, 1) ** 2)
    if s.asymmetry > 0:
        r = r * (1.0 + s.asymmetry * np.cos(phi - s.asymmetry_phase) * equator)
    if s.dimple > 0:  # cavity around the peduncle (polar angle < ~25 deg)
        polar = np.arccos(np.clip(d @ _cavity_dir(s), -1, 1))
        r = r * (1.0 - s.dimple * np.exp(-(polar / s.cavity_width) ** 2))
    return r


def _cavity_dir(s: PepperShape) -> np.ndarray:
    """Unit direction of the stem cavity's centre (+z unless offset)."""
    o, a = s.cavity_offset, s.cavity_phase
    return np.array([np.sin(o) * np.cos(a), np.sin(o) * np.sin(a), np.cos(o)])


def _bend(v: np.ndarray, s: PepperShape) -> np.ndarray:
    """x-y shift k z^2 along azimuth ``bend_phase`` (a bijection)."""
    if s.bend == 0:
        return v
    out = v.copy()
    h = np.array([np.cos(s.bend_phase), np.sin(s.bend_phase)])
    out[:, :2] += s.bend * out[:, 2:3] ** 2 * h
    return out


def _cone(v: np.ndarray, s: PepperShape) -> np.ndarray:
    """Scales x-y by a positive function of z (narrower toward -z)."""
    if s.cone <= 0:
        return v
    c = 0.5 * s.size[2]
    zn = np.clip(v[:, 2] / c, -1.0, 1.0)
    f = 1.0 - s.cone * 0.5 * (1.0 - zn)
    out = v.copy()
    out[:, :2] *= f[:, None]
    return out


def RayHitDistance(mesh: trimesh.Trimesh, origin, direction) -> float:
    """Distance (m) along the ray to the first hit with ``mesh`` (inf if none)."""
    import open3d as o3d
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(_ToOpen3d(mesh)))
    rays = o3d.core.Tensor(np.r_[origin, direction][None].astype(np.float32))
    return float(scene.cast_rays(rays)["t_hit"].numpy()[0])


def _ToOpen3d(mesh: trimesh.Trimesh):
    import open3d as o3d
    return o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(mesh.vertices)),
                                     o3d.utility.Vector3iVector(np.asarray(mesh.faces)))


def MakePepper(shape: PepperShape, subdivisions: int = 4) -> Pepper:
    """The watertight mesh of ``shape`` in the canonical frame (centroid =
    centre of mass at the origin, peduncle on +z) and its peduncle point."""
    shape.validate()
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    d = sphere.vertices / np.linalg.norm(sphere.vertices, axis=1, keepdims=True)
    v = _bend(_cone(d * _radius(d, shape)[:, None], shape), shape)
    mesh = trimesh.Trimesh(vertices=v, faces=sphere.faces, process=True)
    com = mesh.center_mass.copy()
    mesh.apply_translation(-com)
    if shape.cavity_offset > 0 or shape.bend != 0:
        # The peduncle leaves from the bottom of the (off-axis) cavity.
        c = _cavity_dir(shape)[None]
        p = _bend(_cone(c * _radius(c, shape)[:, None], shape), shape)[0] - com
        return _WithPeduncle(Pepper(mesh=mesh, p_O_peduncle=p, shape=shape))
    top = _cone(np.array([[0.0, 0.0, 1.0]]) * _radius(np.array([[0.0, 0.0, 1.0]]), shape),
                shape)[0]
    # The attachment point is where the +z axis through the centroid leaves
    # the surface (the centroid may be slightly off-axis with asymmetry).
    p = np.array([0.0, 0.0, top[2] - com[2]])
    t_hit = RayHitDistance(mesh, np.zeros(3), np.array([0.0, 0.0, 1.0]))
    if np.isfinite(t_hit):
        p = np.array([0.0, 0.0, t_hit])
    return _WithPeduncle(Pepper(mesh=mesh, p_O_peduncle=np.asarray(p, float), shape=shape))


def _WithPeduncle(pep: Pepper) -> Pepper:
    s = pep.shape
    if s.peduncle_length <= 0:
        return pep
    base = pep.p_O_peduncle - np.array([0.0, 0.0, 0.004])    # 4 mm inside the fruit
    pep.peduncle = MakePeduncle(base, s.peduncle_angle, s.peduncle_azimuth,
                                s.peduncle_length + 0.004, s.peduncle_radius)
    pep.p_O_peduncle_tip = _ArcPoint(base, s.peduncle_angle, s.peduncle_azimuth,
                                     s.peduncle_length + 0.004)
    return pep


def _ArcPoint(p0, angle: float, azimuth: float, length: float) -> np.ndarray:
    return _Arc(np.asarray(p0, float), angle, azimuth, np.array([length]))[0][0]


def _Arc(p0, angle, azimuth, s):
    """Centre line and unit tangents of a circular arc from ``p0`` starting
    along +z and turning by ``angle`` toward ``azimuth`` over length s[-1]."""
    h = np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
    ez = np.array([0.0, 0.0, 1.0])
    if angle < 1e-6:
        return p0 + np.outer(s, ez), np.tile(ez, (len(s), 1))
    rc = s[-1] / angle
    th = s / rc
    c = p0 + np.outer(rc * np.sin(th), ez) + np.outer(rc * (1 - np.cos(th)), h)
    t = np.outer(np.cos(th), ez) + np.outer(np.sin(th), h)
    return c, t


def MakePeduncle(p0, angle: float, azimuth: float, length: float, radius: float,
                 ring: int = 12, segments: int = 24) -> trimesh.Trimesh:
    """A capped tube (m) from ``p0`` starting along +z and bending, as a
    circular arc of ``length``, to ``angle`` (rad) off +z toward ``azimuth``
    at its end. Watertight."""
    s = np.linspace(0.0, length, segments + 1)
    c, t = _Arc(np.asarray(p0, float), angle, azimuth, s)
    verts, faces = [], []
    ang = np.linspace(0, 2 * np.pi, ring, endpoint=False)
    for ci, ti in zip(c, t):
        u = np.cross(ti, [0.0, 1.0, 0.0]) if abs(ti[1]) < 0.9 else np.cross(ti, [1.0, 0, 0])
        u = u / np.linalg.norm(u)
        w = np.cross(ti, u)
        verts.append(ci + radius * (np.outer(np.cos(ang), u) + np.outer(np.sin(ang), w)))
    V = np.vstack(verts + [c[:1], c[-1:]])
    nb, nt = len(V) - 2, len(V) - 1
    for i in range(segments):
        for j in range(ring):
            a, b = i * ring + j, i * ring + (j + 1) % ring
            faces += [[a, b, b + ring], [a, b + ring, a + ring]]
    for j in range(ring):
        faces.append([nb, (j + 1) % ring, j])
        a = segments * ring
        faces.append([nt, a + j, a + (j + 1) % ring])
    m = trimesh.Trimesh(V, np.array(faces), process=True)
    trimesh.repair.fix_normals(m)
    return m


def MakePepperMesh(size=(0.075, 0.075, 0.085), lobes: int = 4,
                   lobe_depth: float = 0.08, subdivisions: int = 4) -> trimesh.Trimesh:
    """A star-shaped lobed ellipsoid: an icosphere displaced radially, so it
    is watertight by construction. ``size`` is the full extent (x, y, z)."""
    if lobes < 0 or not 0.0 <= lobe_depth < 0.5:
        raise ValueError("lobes must be >= 0 and lobe_depth in [0, 0.5)")
    shape = PepperShape(size=tuple(float(x) for x in size), lobes=int(lobes),
                        lobe_depth=float(lobe_depth))
    return MakePepper(shape, subdivisions).mesh


def SamplePepperShape(rng: np.random.Generator, variant: str | None = None) -> PepperShape:
    """A random pepper of the family (seeded through ``rng``). Widths are
    5-9 cm, heights 5.5-13 cm; ``variant`` picks one of ``VARIANTS``
    (uniform when None)."""
    if variant is None:
        variant = VARIANTS[int(rng.integers(len(VARIANTS)))]
    u = rng.uniform
    if variant == "blocky":
        w = u(0.065, 0.09)
        size = (w, w * u(0.9, 1.1), w * u(0.85, 1.15))
        sq, cone, taper = u(2.2, 3.0), u(0.0, 0.1), u(0.0, 0.08)
        lobe_depth, dimple, lobe_bottom = u(0.06, 0.18), u(0.15, 0.3), u(0.4, 1.0)
    elif variant == "elongated":
        w = u(0.05, 0.07)
        size = (w, w * u(0.9, 1.1), w * u(1.3, 1.8))
        sq, cone, taper = u(2.0, 2.5), u(0.05, 0.2), u(0.05, 0.15)
        lobe_depth, dimple, lobe_bottom = u(0.04, 0.12), u(0.08, 0.2), u(0.0, 0.6)
    elif variant == "conical":
        w = u(0.06, 0.085)
        size = (w, w * u(0.9, 1.1), w * u(1.0, 1.4))
        sq, cone, taper = u(2.0, 2.6), u(0.25, 0.45), u(0.02, 0.1)
        lobe_depth, dimple, lobe_bottom = u(0.04, 0.14), u(0.1, 0.25), u(0.2, 0.8)
    else:
        raise ValueError(f"variant must be one of {VARIANTS}, got {variant!r}")
    return PepperShape(
        size=tuple(float(x) for x in size), lobes=int(rng.integers(3, 5)),
        lobe_depth=float(lobe_depth), variant=variant, squareness=float(sq),
        shoulder=float(u(0.05, 0.15)), taper=float(taper), cone=float(cone),
        lobe_phase=float(u(0, 2 * np.pi)), asymmetry=float(u(0.0, 0.05)),
        asymmetry_phase=float(u(0, 2 * np.pi)), dimple=float(dimple),
        lobe_bottom=float(lobe_bottom))


def PepperShapeOf(fr) -> PepperShape:
    """The ``PepperShape`` of a ``plants.config.FruitConfig`` (angles in degrees
    there, radians here)."""
    r = np.deg2rad
    return PepperShape(
        size=tuple(fr.size), lobes=fr.lobes, lobe_depth=fr.lobe_depth, variant=fr.variant,
        squareness=fr.squareness, shoulder=fr.shoulder, taper=fr.taper, cone=fr.cone,
        lobe_phase=float(r(fr.lobe_phase_deg)), dimple=fr.dimple,
        cavity_offset=float(r(fr.cavity_offset_deg)), cavity_phase=float(r(fr.cavity_phase_deg)),
        bend=fr.bend, bend_phase=float(r(fr.bend_phase_deg)),
        peduncle_length=fr.peduncle_length if fr.peduncle_curved else 0.0,
        peduncle_angle=float(r(fr.peduncle_angle_deg)),
        peduncle_azimuth=float(r(fr.peduncle_azimuth_deg)),
        peduncle_radius=fr.peduncle_radius)


FAMILY_VERSION = "wide-1"
CUBE_FIT = 0.075    # m: every body of the wide family lies within this of its centroid


def SampleWidePepperShape(rng: np.random.Generator) -> PepperShape:
    """A random member of the wider family (``FAMILY_VERSION``; seeded
    through ``rng``): largest body extent 4-11 cm, height / width 0.75-2.1
    (near-round to elongated), squareness 2-3.2, 0-4 lobes, tapers and
    cones, stem cavities 0-45 % deep, 0.2-0.45 rad wide and up to 0.2 rad
    off the axis, bends up to 2 1/m (7 mm over +-6 cm), and a curved
    peduncle of 1-8 cm whose end leaves 0-60 deg off the axis. The variant
    label is the nearest old one (for bookkeeping only)."""
    u = rng.uniform
    aspect = float(np.exp(u(np.log(0.75), np.log(2.1))))     # height / width
    L = u(0.04, 0.11)                                         # largest extent
    w = L / max(aspect, 1.0)
    size = (w, w * u(0.85, 1.15), w * aspect)
    cone = float(u(0.0, 0.45) if u() < 0.5 else u(0.0, 0.1))
    variant = "elongated" if aspect > 1.3 else ("conical" if cone > 0.2 else "blocky")
    lobes = int(rng.integers(3, 5))
    shape = PepperShape(
        size=tuple(float(x) for x in size), lobes=lobes,
        lobe_depth=float(u(0.0, 0.18)), variant=variant, squareness=float(u(2.0, 3.2)),
        shoulder=float(u(0.0, 0.15)), taper=float(u(0.0, 0.15)), cone=cone,
        lobe_phase=float(u(0, 2 * np.pi)), asymmetry=float(u(0.0, 0.05)),
        asymmetry_phase=float(u(0, 2 * np.pi)), dimple=float(u(0.0, 0.45)),
        lobe_bottom=float(u(0.0, 1.0)), cavity_width=float(u(0.2, 0.45)),
        cavity_offset=float(u(0.0, 0.2)), cavity_phase=float(u(0, 2 * np.pi)),
        bend=float(u(-2.0, 2.0)), bend_phase=float(u(0, 2 * np.pi)),
        peduncle_length=float(u(0.01, 0.08)), peduncle_angle=float(np.radians(u(0, 60))),
        peduncle_azimuth=float(u(0, 2 * np.pi)), peduncle_radius=float(u(0.003, 0.005)))
    # Lobes, shoulders, tapers and the cavity shrink the body: rescale so
    # that its largest extent is L (measured on a coarse mesh).
    f = L / float(MakePepper(dc.replace(shape, peduncle_length=0.0), 2).mesh.extents.max())
    shape.size = tuple(float(x * f) for x in shape.size)
    shape.bend = float(shape.bend / f)
    return shape


_OBJ_TEXTS: dict = {}     # mesh content digest -> OBJ text (``MeshToObjText``)


def MeshToObjText(mesh: trimesh.Trimesh) -> str:
    """Wavefront OBJ text of a triangle mesh with per-vertex normals. The
    text of a mesh already written is kept (by its vertices and faces): a
    multi-fruit episode builds its plant again at every grasp, with the
    same meshes, and writing them took 0.3 s a build."""
    V = np.ascontiguousarray(mesh.vertices, float)
    F = np.ascontiguousarray(mesh.faces, np.int64)
    key = hashlib.sha1(np.asarray(V.shape + F.shape, np.int64).tobytes()
                       + V.tobytes() + F.tobytes()).digest()
    text = _OBJ_TEXTS.get(key)
    if text is None:
        if len(_OBJ_TEXTS) >= 64:
            _OBJ_TEXTS.clear()
        text = _OBJ_TEXTS[key] = _ObjText(mesh)
    return text


def _ObjText(mesh: trimesh.Trimesh) -> str:
    v = "\n".join(f"v {x:.7f} {y:.7f} {z:.7f}" for x, y, z in mesh.vertices)
    n = "\n".join(f"vn {x:.6f} {y:.6f} {z:.6f}" for x, y, z in mesh.vertex_normals)
    f = "\n".join(f"f {i + 1}//{i + 1} {j + 1}//{j + 1} {k + 1}//{k + 1}"
                  for i, j, k in mesh.faces)
    return v + "\n" + n + "\n" + f + "\n"
