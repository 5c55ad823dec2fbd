"""Pepper meshes from files (``plant_scene.fruit.mesh_file``, OBJ / PLY / STL).

Frame convention of the file (F): metres after ``mesh_scale``; +z is the
fruit's peduncle axis and the peduncle leaves the fruit at the top (+z side).
The file's origin does not matter: the fruit is re-centred on its volume
centroid, which becomes the origin of the canonical frame O used by the
plant generator (``p_O = p_F - centroid_F``; no rotation). An optional
``peduncle_file`` (same frame and units) is the stalk: rendered and labelled
as branch, joined to the branch by a straight stalk from its far end.

Checks, in this order, each a ``FruitMeshError`` naming the scenario key and
the file: missing / unreadable / unsupported file, no triangles, size outside
a pepper's (the message suggests ``mesh_scale`` for millimetres, centimetres
or inches; nothing is rescaled silently), not watertight after the repair
below, several large parts, a peduncle that does not reach the fruit's top.

Repair (recorded in ``FruitMesh.repairs`` and in ``ground_truth.json``):
duplicate vertices merged, degenerate and duplicate faces dropped, holes
filled with fans when they add at most ``MAX_HOLE_AREA_FRACTION`` of the
surface, loose parts under ``MAX_LOOSE_PART_FRACTION`` of the volume
dropped, winding and normals made consistent and outward.
"""
from __future__ import annotations

import dataclasses as dc
import functools
from pathlib import Path

import numpy as np
import trimesh

from lmap_drake.errors import InputError
from lmap_drake.limits import MAX_MESH_BYTES, MAX_MESH_FACES

SUFFIXES = (".obj", ".ply", ".stl")
# A pepper's largest extent (m): 3-20 cm real fruits, with margin.
MIN_EXTENT, MAX_EXTENT = 0.02, 0.25
MAX_PEDUNCLE_EXTENT = 0.15
MAX_HOLE_AREA_FRACTION = 0.05
MAX_LOOSE_PART_FRACTION = 0.01
# The peduncle must come within this distance (m) of the fruit surface.
PEDUNCLE_CONTACT = 0.01
UNITS = ((0.001, "millimetres"), (0.01, "centimetres"), (0.0254, "inches"))


class FruitMeshError(InputError, ValueError):
    """A fruit or peduncle mesh file cannot be used; ``key`` is the scenario
    key path, ``detail`` the reason (naming the file)."""

    def __init__(self, key: str, detail: str):
        super().__init__(f"{key} {detail}")
        self.key, self.detail = key, detail


@dc.dataclass
class FruitMesh:
    """A file fruit in its canonical frame O (m; origin = volume centroid,
    +z = peduncle axis). ``p_O_peduncle``: where the peduncle leaves the
    fruit (on the surface); ``peduncle`` (or None) the stalk mesh in O and
    ``p_O_peduncle_tip`` its far end (the point joined to the branch);
    ``centroid_F``: the file-frame position of O's origin (m)."""
    mesh: trimesh.Trimesh
    p_O_peduncle: np.ndarray
    peduncle: trimesh.Trimesh | None
    p_O_peduncle_tip: np.ndarray | None
    centroid_F: np.ndarray
    file: str
    peduncle_file: str
    repairs: list[str]

    @property
    def volume(self) -> float:
        return float(self.mesh.volume)

    def AsPepper(self):
        """The ``plants.pepper.Pepper`` the plant generators place (no
        procedural shape; the stalk mesh, if any, as its curved peduncle)."""
        from lmap_drake.plants.pepper import Pepper
        return Pepper(mesh=self.mesh, p_O_peduncle=self.p_O_peduncle, shape=None,
                      peduncle=self.peduncle, p_O_peduncle_tip=self.p_O_peduncle_tip)


def ResolveMeshPath(name: str) -> Path:
    """An absolute path, or one relative to the current directory, else to
    the repository root (as ``models/...``)."""
    p = Path(name).expanduser()
    if p.is_absolute() or p.exists():
        return p.resolve() if p.exists() else p
    from lmap_drake.paths import REPO_ROOT
    q = REPO_ROOT / p
    return q if q.exists() else p


def _FaceCount(path: Path) -> int | None:
    """The number of faces a mesh file declares (binary STL, PLY header) or
    holds (OBJ ``f`` lines, ASCII STL facets), read without loading it; None
    when it cannot tell (the loader then names the problem)."""
    suffix = path.suffix.lower()
    with open(path, "rb") as f:
        head = f.read(84)
        if suffix == ".stl" and not head.startswith(b"solid") and len(head) == 84:
            return int.from_bytes(head[80:84], "little")
        f.seek(0)
        if suffix == ".ply":
            for _ in range(200):                       # header lines
                line = f.readline(1000).strip()
                if line.startswith(b"element face"):
                    parts = line.split()
                    return int(parts[2]) if len(parts) > 2 and parts[2].isdigit() else None
                if line == b"end_header" or not line:
                    return None
            return None
        marker = b"f" if suffix == ".obj" else b"facet"
        return sum(1 for line in f if line.lstrip().split(b" ", 1)[0] == marker)


def _CheckMeshSize(key: str, path: Path) -> None:
    """The file's size and face count within ``lmap_drake.limits`` before
    it is loaded."""
    size = path.stat().st_size
    if size > MAX_MESH_BYTES:
        raise FruitMeshError(key, f"{path} is {size} bytes, more than the limit of "
                                  f"{MAX_MESH_BYTES}; decimate it")
    faces = _FaceCount(path)
    if faces is not None and faces > MAX_MESH_FACES:
        raise FruitMeshError(key, f"{path} declares {faces} faces, more than the limit of "
                                  f"{MAX_MESH_FACES}; decimate it")


def _read(key: str, name: str) -> trimesh.Trimesh:
    path = ResolveMeshPath(name)
    if not path.exists():
        raise FruitMeshError(key, f"{name}: file not found (relative paths are taken from "
                                  f"the current directory, then the repository root)")
    if path.is_dir():
        raise FruitMeshError(key, f"{path} is a directory, not a mesh file")
    if path.suffix.lower() not in SUFFIXES:
        raise FruitMeshError(key, f"{path}: unsupported format '{path.suffix}'; use "
                                  f"{', '.join(s[1:].upper() for s in SUFFIXES)}")
    _CheckMeshSize(key, path)
    try:
        loaded = trimesh.load(str(path), force="mesh", process=False)
    except Exception as err:  # noqa: BLE001 - any parser failure is a bad file
        raise FruitMeshError(key, f"{path} could not be read as a mesh: "
                                  f"{type(err).__name__}: {' '.join(str(err).split())}") from None
    if isinstance(loaded, trimesh.Trimesh) and len(loaded.faces) > MAX_MESH_FACES:
        raise FruitMeshError(key, f"{path} has {len(loaded.faces)} faces, more than the limit "
                                  f"of {MAX_MESH_FACES}; decimate it")
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0 \
            or len(loaded.vertices) < 4:
        raise FruitMeshError(key, f"{path} holds no triangles (an empty mesh)")
    mesh = trimesh.Trimesh(np.asarray(loaded.vertices, float), np.asarray(loaded.faces),
                           process=False)
    if not np.all(np.isfinite(mesh.vertices)):
        raise FruitMeshError(key, f"{path} has non-finite vertex coordinates")
    return mesh


def _check_size(key: str, path: str, mesh: trimesh.Trimesh, scale: float,
                lo: float, hi: float, what: str) -> None:
    ext = mesh.extents
    big = float(ext.max())
    if lo <= big <= hi:
        return
    raw = big / scale
    hint = ""
    for f, unit in UNITS:
        if 0.03 <= raw * f <= 0.2:
            hint = (f"; if the file is in {unit}, set plant_scene.fruit.mesh_scale: {f:g}")
            break
    if not hint:
        hint = "; no common unit (mm, cm, inch) makes it pepper-sized: check the file"
    dims = " x ".join(f"{x:.4g}" for x in ext)
    raise FruitMeshError(key, f"{path}: {what} is {dims} m across after mesh_scale {scale:g} "
                              f"(largest {big:.4g} m); a pepper's must be {lo:g}-{hi:g} m"
                              f"{hint}")


def _repair(key: str, path: str, mesh: trimesh.Trimesh) -> list[str]:
    """Makes ``mesh`` a single watertight, outward-oriented solid in place
    (see the module docstring), or raises FruitMeshError."""
    done = []
    n_f = len(mesh.faces)
    mesh.merge_vertices()
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.update_faces(mesh.unique_faces())
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) != n_f:     # (merging an STL's unshared vertices is no repair)
        done.append(f"dropped {n_f - len(mesh.faces)} degenerate or duplicate faces")
    if len(mesh.faces) == 0:
        raise FruitMeshError(key, f"{path} holds no non-degenerate triangles")
    if not mesh.is_watertight:
        area = float(mesh.area)
        trimesh.repair.fill_holes(mesh, use_fan=True)
        added = float(mesh.area) - area
        if mesh.is_watertight and added > MAX_HOLE_AREA_FRACTION * float(mesh.area):
            raise FruitMeshError(
                key, f"{path} is not watertight and its holes are too large to fill without "
                     f"guessing the shape ({100 * added / mesh.area:.0f} % of the surface; at "
                     f"most {100 * MAX_HOLE_AREA_FRACTION:.0f} % is repaired): close the mesh "
                     f"in a mesh editor (e.g. MeshLab's 'Close Holes', Blender's 3D-print "
                     f"toolbox)")
        if mesh.is_watertight:
            done.append(f"filled holes ({100 * added / mesh.area:.2f} % of the surface)")
    if not mesh.is_watertight:
        edges = trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1)
        raise FruitMeshError(
            key, f"{path} is not watertight and could not be repaired ({len(edges)} open "
                 f"boundary edges after filling holes; non-manifold or self-overlapping "
                 f"surfaces are not repaired): close the mesh in a mesh editor (e.g. MeshLab's "
                 f"'Close Holes', Blender's 3D-print toolbox)")
    parts = mesh.split(only_watertight=False)
    if len(parts) > 1:
        vols = np.array([abs(p.volume) for p in parts])
        keep = vols >= MAX_LOOSE_PART_FRACTION * vols.max()
        if keep.sum() > 1:
            raise FruitMeshError(key, f"{path} holds {int(keep.sum())} separate solids; a "
                                      f"fruit file must hold one pepper")
        big = parts[int(np.argmax(vols))]
        mesh.vertices, mesh.faces = big.vertices, big.faces
        done.append(f"dropped {len(parts) - 1} loose part(s) under "
                    f"{100 * MAX_LOOSE_PART_FRACTION:g} % of the volume")
    flipped = mesh.volume < 0
    trimesh.repair.fix_normals(mesh)
    if flipped:
        done.append("turned the faces outward (the file's winding was inside-out)")
    if not mesh.is_watertight or not mesh.is_winding_consistent or mesh.volume <= 0:
        raise FruitMeshError(key, f"{path}: could not orient the surface consistently "
                                  f"(a non-manifold or self-intersecting mesh)")
    return done


def _closest(mesh: trimesh.Trimesh, points) -> tuple[np.ndarray, np.ndarray]:
    """Closest surface points of ``mesh`` and their distances (m), open3d."""
    import open3d as o3d
    sc = o3d.t.geometry.RaycastingScene()
    sc.add_triangles(o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)),
                     o3d.core.Tensor(np.asarray(mesh.faces, np.uint32)))
    q = np.asarray(points, float).reshape(-1, 3)
    c = sc.compute_closest_points(o3d.core.Tensor(q.astype(np.float32)))["points"].numpy()
    c = c.astype(float)
    return c, np.linalg.norm(c - q, axis=1)


def _ray_hit(mesh: trimesh.Trimesh, origin, direction) -> float:
    from lmap_drake.plants.pepper import RayHitDistance
    return RayHitDistance(mesh, np.asarray(origin, float), np.asarray(direction, float))


def _LoadFruitMesh(mesh_file: str, peduncle_file: str, scale: float,
                   peduncle_point: tuple) -> FruitMesh:
    key = "plant_scene.fruit.mesh_file"
    if not np.isfinite(scale) or scale <= 0:
        raise FruitMeshError("plant_scene.fruit.mesh_scale", f"must be > 0, got {scale}")
    path = str(ResolveMeshPath(mesh_file))
    mesh = _read(key, mesh_file)
    mesh.apply_scale(scale)
    _check_size(key, path, mesh, scale, MIN_EXTENT, MAX_EXTENT, "the fruit")
    repairs = _repair(key, path, mesh)
    _check_size(key, path, mesh, scale, MIN_EXTENT, MAX_EXTENT, "the fruit")
    if float(mesh.extents.min()) < 0.2 * float(mesh.extents.max()):
        raise FruitMeshError(key, f"{path}: the fruit is {' x '.join(f'{x:.3g}' for x in mesh.extents)} "
                                  f"m, too flat for a pepper (smallest extent under 20 % of the "
                                  f"largest)")
    c_F = np.asarray(mesh.center_mass, float)
    mesh.apply_translation(-c_F)
    # Where the peduncle leaves the fruit and where the stalk's far end is.
    ped, tip = None, None
    if peduncle_file:
        pkey = "plant_scene.fruit.peduncle_file"
        ppath = str(ResolveMeshPath(peduncle_file))
        ped = _read(pkey, peduncle_file)
        ped.apply_scale(scale)
        ped.merge_vertices()
        _check_size(pkey, ppath, ped, scale, 0.002, MAX_PEDUNCLE_EXTENT, "the peduncle")
        ped.apply_translation(-c_F)
        trimesh.repair.fix_winding(ped)
        V = np.asarray(ped.vertices)
        _, dist = _closest(mesh, V)
        if dist.min() > PEDUNCLE_CONTACT:
            raise FruitMeshError(pkey, f"{ppath}: the peduncle comes no closer than "
                                       f"{dist.min() * 100:.1f} cm to the fruit in "
                                       f"{path} (at most {PEDUNCLE_CONTACT * 100:g} cm): both "
                                       f"files must share one frame and unit")
        base_V = V[dist <= dist.min() + 0.002].mean(0)
        if base_V[2] <= 0 or V.mean(0)[2] <= 0:
            raise FruitMeshError(pkey, f"{ppath}: the peduncle is not on the fruit's top "
                                       f"(+z) side; the convention is +z = peduncle axis, "
                                       f"peduncle at the top: rotate the files")
        closest, _ = _closest(mesh, base_V[None])
        p_ped = closest[0]
        tip = V[int(np.argmax(np.linalg.norm(V - p_ped, axis=1)))].copy()
    if len(peduncle_point):
        p_F = np.asarray(peduncle_point, float) * scale
        closest, dist = _closest(mesh, (p_F - c_F)[None])
        if dist[0] > 0.005:
            raise FruitMeshError("plant_scene.fruit.peduncle_point",
                                 f"{list(peduncle_point)} is {dist[0] * 100:.1f} cm from the "
                                 f"surface of {path} (at most 0.5 cm)")
        p_ped = closest[0]
    elif ped is None:
        t = _ray_hit(mesh, np.zeros(3), [0.0, 0.0, 1.0])
        if np.isfinite(t):
            p_ped = np.array([0.0, 0.0, t])
        else:   # the centroid is outside the solid: the top vertex nearest the axis
            V = np.asarray(mesh.vertices)
            top = V[:, 2] > V[:, 2].max() - 0.005
            p_ped = V[top][int(np.argmin(np.linalg.norm(V[top, :2], axis=1)))].copy()
    return FruitMesh(mesh=mesh, p_O_peduncle=np.asarray(p_ped, float), peduncle=ped,
                     p_O_peduncle_tip=tip, centroid_F=c_F, file=path,
                     peduncle_file=str(ResolveMeshPath(peduncle_file)) if peduncle_file else "",
                     repairs=repairs)


@functools.lru_cache(maxsize=32)
def _Cached(mesh_file, peduncle_file, scale, peduncle_point, stamp):
    return _LoadFruitMesh(mesh_file, peduncle_file, scale, peduncle_point)


def _stamp(name: str):
    p = ResolveMeshPath(name) if name else None
    try:
        st = p.stat() if p is not None else None
        return (str(p), st.st_mtime_ns, st.st_size) if st else None
    except OSError:
        return None


def LoadFruitMesh(mesh_file: str, peduncle_file: str = "", scale: float = 1.0,
                  peduncle_point=()) -> FruitMesh:
    """The checked, repaired fruit of ``mesh_file`` (see the module
    docstring); cached per file contents stamp. Do not mutate the result's
    meshes (copy them)."""
    return _Cached(str(mesh_file), str(peduncle_file or ""), float(scale),
                   tuple(float(x) for x in peduncle_point),
                   (_stamp(mesh_file), _stamp(peduncle_file)))


def LoadFruitMeshOf(fruit_cfg) -> FruitMesh:
    """``LoadFruitMesh`` of a ``FruitConfig`` with ``mesh_file`` set."""
    return LoadFruitMesh(fruit_cfg.mesh_file, fruit_cfg.peduncle_file, fruit_cfg.mesh_scale,
                         fruit_cfg.peduncle_point)


def FruitMeshFolder(folder, option: str = "--fruit_mesh_dir") -> dict:
    """NAME -> (fruit file, peduncle file or "") for every
    ``folder/NAME.{obj,ply,stl}`` (``NAME.peduncle.*`` are the stalks), in
    name order; InputError naming ``option`` when the folder is missing,
    holds no mesh or two meshes of one name. The files are not read here
    (``LoadFruitMesh`` checks them)."""
    d = Path(folder)
    if not d.is_dir():
        raise InputError(f"{option} {folder}: not a folder")
    files = sorted(f for f in d.iterdir() if f.suffix.lower() in SUFFIXES
                   and not f.stem.endswith(".peduncle"))
    if not files:
        raise InputError(f"{option} {folder} holds no .obj, .ply or .stl mesh")
    out = {}
    for f in files:
        if f.stem in out:
            raise InputError(f"{option} {folder}: two meshes named {f.stem} "
                             f"({out[f.stem][0].name}, {f.name})")
        peds = [d / f"{f.stem}.peduncle{x}" for x in SUFFIXES]
        peds = [q for q in peds if q.is_file()]
        out[f.stem] = (f, peds[0] if peds else "")
    return out
