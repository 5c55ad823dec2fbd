"""Sweet-pepper-like watertight meshes (metres, canonical frame O: centroid
at the origin, peduncle along +z).

The pepper shape family used everywhere in the project (plant-world
scenarios, DeepSDF training, shape-completion benchmarks):

* ``PepperShape``: the parameters of one pepper (metres / dimensionless).
* ``SamplePepperShape(rng)``: a seeded random member of the family (three
  variants: ``blocky``, ``elongated``, ``conical``).
* ``MakePepper(shape)``: the mesh in the canonical frame plus the peduncle
  attachment point ``p_O_peduncle`` (on the surface, on the +z axis).
* ``MakePepperMesh(size, lobes, lobe_depth, subdivisions)``: the original
  call used by the station (unchanged output).

Every mesh is an icosphere displaced radially (star-shaped about the origin)
followed by an x-y scaling that depends only on z (a bijection of R^3), so
it is watertight and free of self-intersections by construction.
"""
from __future__ import annotations

import dataclasses as dc

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
        if not (0 <= self.dimple <= 0.3 and 0 <= self.lobe_bottom <= 1):
            raise ValueError("dimple in [0, 0.3], lobe_bottom in [0, 1]")
        if self.variant not in VARIANTS:
            raise ValueError(f"variant must be one of {VARIANTS}")


@dc.dataclass
class Pepper:
    """A pepper mesh in its canonical frame O (m) and the peduncle
    attachment point on top (m, on the +z axis)."""
    mesh: trimesh.Trimesh
    p_O_peduncle: np.ndarray
    shape: PepperShape


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
        polar = np.arccos(np.clip(d[:, 2], -1, 1))
        r = r * (1.0 - s.dimple * np.exp(-(polar / 0.3) ** 2))
    return r


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


def _RayHitDistance(mesh: trimesh.Trimesh, origin, direction) -> float:
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
    v = _cone(d * _radius(d, shape)[:, None], shape)
    mesh = trimesh.Trimesh(vertices=v, faces=sphere.faces, process=True)
    com = mesh.center_mass.copy()
    mesh.apply_translation(-com)
    top = _cone(np.array([[0.0, 0.0, 1.0]]) * _radius(np.array([[0.0, 0.0, 1.0]]), shape),
                shape)[0]
    # The attachment point is where the +z axis through the centroid leaves
    # the surface (the centroid may be slightly off-axis with asymmetry).
    p = np.array([0.0, 0.0, top[2] - com[2]])
    t_hit = _RayHitDistance(mesh, np.zeros(3), np.array([0.0, 0.0, 1.0]))
    if np.isfinite(t_hit):
        p = np.array([0.0, 0.0, t_hit])
    return Pepper(mesh=mesh, p_O_peduncle=np.asarray(p, float), shape=shape)


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


def MeshToObjText(mesh: trimesh.Trimesh) -> str:
    """Wavefront OBJ text of a triangle mesh with per-vertex normals."""
    v = "\n".join(f"v {x:.7f} {y:.7f} {z:.7f}" for x, y, z in mesh.vertices)
    n = "\n".join(f"vn {x:.6f} {y:.6f} {z:.6f}" for x, y, z in mesh.vertex_normals)
    f = "\n".join(f"f {i + 1}//{i + 1} {j + 1}//{j + 1} {k + 1}//{k + 1}"
                  for i, j, k in mesh.faces)
    return v + "\n" + n + "\n" + f + "\n"
