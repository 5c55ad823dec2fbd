"""Plants from mesh files (``plant_scene.kind: mesh_plant``): reading and
checking the files. A plant is stems, leaves and fruits given as separate
files in ``stems/ leaves/ fruits/`` subfolders of a plant folder, as a
manifest YAML that lists files with a part type, or as the parts of one
glTF / OBJ named by prefix; OBJ, PLY, STL, glTF and GLB through trimesh.

Every part is returned in the plant frame P (metres: the files' units times
``scale``; z up: a Y-up file is turned). A leaf becomes a ``LeafSheet``
(``mesh_plant_leaves``: an alpha card cut to its outline, or a surface).

Bad files raise ``MeshPlantError`` naming the scenario key and the file
(missing, unreadable, empty, non-finite, wrong size for the units, a leaf
without area, no fruit, no stem), before anything is built. See
docs/how-to/bring-your-own-plant.md for the format.
"""
from __future__ import annotations

import dataclasses as dc
import functools
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import trimesh
import yaml

from lmap_drake.errors import InputError
from lmap_drake.limits import MAX_MESH_FACES, CheckYamlLimits, ReadBounded
from lmap_drake.plants.fruit_mesh import (MAX_EXTENT, MIN_EXTENT, UNITS, FruitMeshError,
                                          ResolveMeshPath, _CheckMeshSize, _repair)
from lmap_drake.plants.generator import PlantGenerationError
from lmap_drake.plants.mesh_plant_leaves import CardSheet, LeafSheet, SurfaceSheet

KEY = "plant_scene.mesh_plant"
SUFFIXES = (".obj", ".ply", ".stl", ".gltf", ".glb")
PART_KINDS = ("stem", "leaf", "fruit")
SUBFOLDERS = {"stems": "stem", "leaves": "leaf", "fruits": "fruit"}
MANIFEST = "plant.yaml"
MANIFEST_KEYS = ("file", "part", "name", "color", "target", "attach")
# name prefixes of the parts inside one file (lower case); "ignore" parts are skipped
PREFIXES = (("stem", "stem"), ("stalk", "stem"), ("branch", "stem"), ("shoot", "stem"),
            ("peduncle", "stem"), ("leaf", "leaf"), ("fruit", "fruit"), ("pepper", "fruit"))
LEAF_EXTENT = (0.01, 0.6)        # m, a leaf's largest extent
PLANT_EXTENT = (0.05, 4.0)       # m, the whole plant's
MIN_LEAF_AREA = 1e-4             # m^2 (1 cm^2)


class MeshPlantError(PlantGenerationError):
    """A bad plant file or ``plant_scene.mesh_plant`` value; ``key`` names
    the scenario key, ``detail`` the file (and manifest entry) and what is
    wrong."""

    def __init__(self, key: str, detail: str):
        super().__init__(f"{key} {detail}")
        self.key, self.detail = key, detail


@dc.dataclass
class MeshPart:
    """One stem, leaf or fruit (plant frame P, m). ``mesh``: its triangles
    (a leaf card: the cut-out surface); ``uv`` / ``image``: texture
    coordinates per vertex and the RGBA texture (PIL) or None; ``color``:
    RGBA 0-1 from the manifest or the file's material, or None; ``sheet``:
    a leaf's ``LeafSheet``; ``card``: cut from an alpha texture; ``render``:
    a fruit's mesh as the file gives it (``mesh`` is the repaired solid;
    ``uv`` belongs to ``render``)."""
    kind: str
    name: str
    source: str
    key: str
    mesh: trimesh.Trimesh
    uv: np.ndarray | None = None
    image: object = None
    color: tuple | None = None
    target: bool | None = None
    attach: np.ndarray | None = None
    sheet: LeafSheet | None = None
    card: bool = False
    repairs: list = dc.field(default_factory=list)
    render: trimesh.Trimesh | None = None


def _Unit(v):
    v = np.asarray(v, float)
    return v / max(float(np.linalg.norm(v)), 1e-12)


def _ScaleHint(extent: float, scale: float, lo: float, hi: float) -> str:
    raw = extent / scale
    for f, unit in UNITS:
        if lo <= raw * f <= hi:
            return f"; if the files are in {unit}, set {KEY}.scale: {f:g}"
    return "; check the files' units and plant_scene.mesh_plant.scale"


def _CheckExtent(key, source, what, mesh, scale, lo, hi) -> None:
    big = float(mesh.extents.max()) if len(mesh.vertices) else 0.0
    if not lo <= big <= hi:
        raise MeshPlantError(key, f"{source}: {what} is {big:.4g} m across after scale "
                                  f"{scale:g}; it must be {lo:g}-{hi:g} m"
                                  f"{_ScaleHint(big, scale, lo, hi)}")


def _Material(geom) -> tuple:
    """(uv, RGBA PIL image or None, RGBA 0-1 or None) of a trimesh geometry."""
    vis = getattr(geom, "visual", None)
    uv, image, color = None, None, None
    if isinstance(vis, trimesh.visual.texture.TextureVisuals):
        mat = vis.material
        image = getattr(mat, "image", None) or getattr(mat, "baseColorTexture", None)
        c = getattr(mat, "diffuse", None)
        if c is None:
            c = getattr(mat, "baseColorFactor", None)
        if c is not None:
            color = tuple(float(x) / 255.0 for x in np.asarray(c, float)[:4])
        if vis.uv is not None and len(vis.uv) == len(geom.vertices) and image is not None:
            uv = np.asarray(vis.uv, float)
            image = image.convert("RGBA")
            color = None                  # the texture gives the colour
        else:
            image = None
    elif isinstance(vis, trimesh.visual.color.ColorVisuals) and vis.defined:
        color = tuple(float(x) / 255.0 for x in np.asarray(vis.face_colors, float).mean(0))
    return uv, image, color


def _Read(key: str, name: str, base: Path) -> trimesh.Scene:
    """The file ``name`` (relative to ``base``) as a trimesh Scene."""
    path = Path(name).expanduser()
    path = path if path.is_absolute() else base / path
    if not path.exists():
        raise MeshPlantError(key, f"{path}: file not found")
    if path.is_dir():
        raise MeshPlantError(key, f"{path} is a directory, not a mesh file")
    if path.suffix.lower() not in SUFFIXES:
        raise MeshPlantError(key, f"{path}: unsupported format '{path.suffix}'; use "
                                  f"{', '.join(s[1:].upper() for s in SUFFIXES)}")
    try:
        _CheckMeshSize(key, path)
    except FruitMeshError as err:
        raise MeshPlantError(key, err.detail) from None
    try:
        scene = trimesh.load_scene(str(path), process=False)
    except Exception as err:  # noqa: BLE001 - any parser failure is a bad file
        raise MeshPlantError(key, f"{path} could not be read as a mesh: {type(err).__name__}: "
                                  f"{' '.join(str(err).split())[:200]}") from None
    geoms = [g for g in scene.geometry.values() if isinstance(g, trimesh.Trimesh)]
    if not geoms or sum(len(g.faces) for g in geoms) == 0:
        raise MeshPlantError(key, f"{path} holds no triangles (an empty mesh)")
    if sum(len(g.faces) for g in geoms) > MAX_MESH_FACES:
        raise MeshPlantError(key, f"{path} has more than {MAX_MESH_FACES} faces; decimate it")
    for g in geoms:
        if not np.all(np.isfinite(g.vertices)):
            raise MeshPlantError(key, f"{path} has non-finite vertex coordinates")
    return scene


def _Nodes(scene: trimesh.Scene) -> list:
    """(name, geometry moved by its node transform) of every mesh in ``scene``."""
    out = []
    for node in scene.graph.nodes_geometry:
        T, gname = scene.graph[node]
        g = scene.geometry.get(gname)
        if isinstance(g, trimesh.Trimesh) and len(g.faces):
            g = g.copy()
            g.apply_transform(T)
            out.append((str(node) if node != gname else str(gname), g))
    return out


def _Up(mesh: trimesh.Trimesh, up: str) -> None:
    if up == "y":        # Y-up (glTF) to Z-up: (x, y, z) -> (x, -z, y)
        mesh.apply_transform(np.array([[1, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0],
                                       [0, 0, 0, 1.0]]))


def _Join(geoms: list) -> tuple:
    """One mesh of ``geoms`` with the first's texture if it is the only one."""
    if len(geoms) == 1:
        uv, image, color = _Material(geoms[0])
        g = geoms[0]
        return trimesh.Trimesh(np.asarray(g.vertices, float), np.asarray(g.faces),
                               process=False), uv, image, color
    colors = [c for c in (_Material(g)[2] for g in geoms) if c is not None]
    mesh = trimesh.util.concatenate([trimesh.Trimesh(g.vertices, g.faces, process=False)
                                     for g in geoms])
    return mesh, None, None, (tuple(np.mean(colors, 0)) if colors else None)


def _Part(kind, name, source, key, geoms, scale, up, entry) -> MeshPart:
    mesh, uv, image, color = _Join(geoms)
    mesh.apply_scale(scale)
    _Up(mesh, up)
    if entry.get("color") is not None:
        c = entry["color"]
        if not (isinstance(c, list) and len(c) in (3, 4)
                and all(isinstance(x, (int, float)) and 0 <= x <= 1 for x in c)):
            raise MeshPlantError(key, f"{source}: color must be [r, g, b] or [r, g, b, a] in "
                                      f"0-1, got {c!r}")
        color = tuple(float(x) for x in c) + ((1.0,) if len(c) == 3 else ())
    attach = entry.get("attach")
    if attach is not None:
        if not (isinstance(attach, list) and len(attach) == 3
                and all(isinstance(x, (int, float)) and np.isfinite(x) for x in attach)):
            raise MeshPlantError(key, f"{source}: attach must be [x, y, z], got {attach!r}")
        a = np.asarray(attach, float) * scale
        attach = np.array([a[0], -a[2], a[1]]) if up == "y" else a
    target = entry.get("target")
    if target is not None and not isinstance(target, bool):
        raise MeshPlantError(key, f"{source}: target must be true or false, got {target!r}")
    return MeshPart(kind=kind, name=name, source=source, key=key, mesh=mesh, uv=uv,
                    image=image, color=color, target=target, attach=attach)


# --- leaves -----------------------------------------------------------------

def _LeafSheet(part: MeshPart, threshold: float) -> None:
    sheet = CardSheet(part.mesh.vertices, part.mesh.faces, part.uv, part.image, threshold)
    part.card = sheet is not None
    if sheet is None:
        sheet = SurfaceSheet(part.mesh)
    if len(sheet.outline) < 3 or sheet.area < MIN_LEAF_AREA:
        what = "its texture's alpha outline" if part.card else "its surface"
        raise MeshPlantError(part.key, f"{part.source}: the leaf has no area ({what} covers "
                                       f"{sheet.area * 1e4:.2g} cm^2, at least "
                                       f"{MIN_LEAF_AREA * 1e4:g} cm^2)")
    part.sheet = sheet


# --- the whole plant --------------------------------------------------------

def _Entries(mp) -> tuple[list, Path, float, str]:
    """(entries, base folder, manifest scale, manifest up axis): the parts
    the config names, each a dict with ``file``, ``part`` and the manifest's
    other keys plus ``key`` (scenario key path of the entry)."""
    if sum(bool(x) for x in (mp.folder, mp.manifest, mp.file)) != 1:
        raise MeshPlantError(KEY, "needs exactly one of folder, manifest or file (the plant's "
                                  "files), got " + (", ".join(
                                      k for k in ("folder", "manifest", "file")
                                      if getattr(mp, k)) or "none"))
    if mp.file:
        p = ResolveMeshPath(mp.file)
        return [{"file": str(p), "part": "named", "key": f"{KEY}.file"}], p.parent, 1.0, ""
    if mp.folder:
        folder = ResolveMeshPath(mp.folder)
        if not folder.is_dir():
            raise MeshPlantError(f"{KEY}.folder", f"{mp.folder}: not a folder")
        if (folder / MANIFEST).is_file():
            return _Manifest(folder / MANIFEST, f"{KEY}.folder")
        entries = []
        for sub, kind in SUBFOLDERS.items():
            if (folder / sub).is_dir():
                for f in sorted((folder / sub).iterdir()):
                    if f.suffix.lower() in SUFFIXES:
                        entries.append({"file": str(f), "part": kind, "key": f"{KEY}.folder"})
        if not entries:
            raise MeshPlantError(f"{KEY}.folder", f"{folder} has no {MANIFEST} and no mesh "
                                                  f"file in stems/, leaves/ or fruits/")
        return entries, folder, 1.0, ""
    path = ResolveMeshPath(mp.manifest)
    if not path.is_file():
        raise MeshPlantError(f"{KEY}.manifest", f"{mp.manifest}: file not found")
    return _Manifest(path, f"{KEY}.manifest")


def _Manifest(path: Path, key: str) -> tuple[list, Path, float, str]:
    try:
        text = ReadBounded(path, 1_000_000, "manifest").decode("utf-8")
        CheckYamlLimits(text, str(path))
        data = yaml.safe_load(text)
    except (InputError, yaml.YAMLError, UnicodeDecodeError, OSError) as err:
        raise MeshPlantError(key, f"{path} could not be read as YAML: "
                                  f"{' '.join(str(err).split())[:200]}") from None
    if not isinstance(data, dict) or not isinstance(data.get("parts"), list):
        raise MeshPlantError(key, f"{path}: needs a 'parts' list (see "
                                  f"docs/how-to/bring-your-own-plant.md)")
    unknown = sorted(set(data) - {"parts", "scale", "up_axis"})
    if unknown:
        raise MeshPlantError(key, f"{path}: unknown key(s) {unknown}")
    scale = data.get("scale", 1.0)
    if not isinstance(scale, (int, float)) or not np.isfinite(scale) or scale <= 0:
        raise MeshPlantError(key, f"{path}: scale must be a number > 0, got {scale!r}")
    up = data.get("up_axis", "")
    if up not in ("", "y", "z"):
        raise MeshPlantError(key, f"{path}: up_axis must be y or z, got {up!r}")
    entries = []
    for i, e in enumerate(data["parts"]):
        k = key
        if not isinstance(e, dict) or not isinstance(e.get("file"), str):
            raise MeshPlantError(k, f"{path}: each part needs 'file', got {e!r}")
        bad = sorted(set(e) - set(MANIFEST_KEYS))
        if bad:
            raise MeshPlantError(k, f"{path}: unknown key(s) {bad}; known: "
                                    f"{', '.join(MANIFEST_KEYS)}")
        part = e.get("part", "named")
        if part not in PART_KINDS + ("named",):
            raise MeshPlantError(k, f"{path}: part must be stem, leaf, fruit or named, "
                                    f"got {part!r}")
        entries.append(dict(e, part=part, key=k, where=f"{path} parts[{i}]"))
    return entries, path.parent, float(scale), up


def _NamedKind(name: str):
    low = name.lower().lstrip("_")
    if low.startswith("ignore"):
        return None
    for prefix, kind in PREFIXES:
        if low.startswith(prefix):
            return kind
    return ""


def LoadMeshPlantParts(mp) -> list[MeshPart]:
    """Every part of a ``MeshPlantConfig`` ``mp`` (plant frame, m), checked
    (see the module docstring); cached per config and file stamps."""
    return _Cached(mp.folder, mp.manifest, mp.file, float(mp.scale), mp.up_axis,
                   float(mp.alpha_threshold), FileStamps(mp))


def FileStamps(mp) -> tuple:
    """(path, mtime, size) of every file ``mp`` names (and of the manifest
    or folder), so that a changed file is read again."""
    entries, base, _, _ = _Entries(mp)
    stamps = []
    for p in [Path(e["file"]) if Path(e["file"]).is_absolute() else base / e["file"]
              for e in entries] + [ResolveMeshPath(mp.folder or mp.manifest or mp.file)]:
        try:
            st = p.stat()
            stamps.append((str(p), st.st_mtime_ns, st.st_size))
        except OSError:
            stamps.append((str(p), None))
    return tuple(stamps)


def _EntryParts(e: dict, base: Path, scale: float, up_axis: str, m_up: str) -> list:
    """The parts of one entry (a file, or the named parts of one file)."""
    scene = _Read(e["key"], e["file"], base)
    src = str(Path(e["file"]) if Path(e["file"]).is_absolute() else base / e["file"])
    suffix = Path(src).suffix.lower()
    up = m_up or (up_axis if up_axis != "auto" else
                  ("y" if suffix in (".gltf", ".glb") else "z"))
    out: list[MeshPart] = []
    if e["part"] == "named":
        groups: dict = {}
        for name, g in _Nodes(scene):
            kind = _NamedKind(name)
            if kind is None:
                continue
            if not kind:
                raise MeshPlantError(e["key"], f"{src}: part '{name}' is named with none "
                                               f"of the prefixes stem, leaf, fruit (or "
                                               f"ignore)")
            groups.setdefault((kind, name), []).append(g)
        for (kind, name), geoms in groups.items():
            out.append(_Part(kind, name, f"{src}#{name}", e["key"], geoms, scale, up, e))
    else:
        name = e.get("name") or Path(src).stem
        out.append(_Part(e["part"], name, src, e["key"], [g for _, g in _Nodes(scene)],
                         scale, up, e))
    return out


@functools.lru_cache(maxsize=8)
def _Cached(folder, manifest, file, scale, up_axis, threshold, stamps) -> list[MeshPart]:
    mp = SimpleNamespace(folder=folder, manifest=manifest, file=file)
    entries, base, m_scale, m_up = _Entries(mp)
    if not (np.isfinite(scale) and scale > 0):
        raise MeshPlantError(f"{KEY}.scale", f"must be > 0, got {scale}")
    scale *= m_scale
    parts: list[MeshPart] = []
    for e in entries:
        try:
            parts += _EntryParts(e, base, scale, up_axis, m_up)
        except MeshPlantError as err:
            if "where" not in e:
                raise
            raise MeshPlantError(err.key, f"{e['where']}: {err.detail}") from None
    for p in parts:
        if p.kind == "fruit":
            _CheckExtent(p.key, p.source, "the fruit", p.mesh, scale, MIN_EXTENT, MAX_EXTENT)
            p.render = p.mesh.copy()
            try:
                p.repairs = _repair(p.key, p.source, p.mesh)
            except FruitMeshError as err:
                raise MeshPlantError(p.key, err.detail) from None
        elif p.kind == "leaf":
            _CheckExtent(p.key, p.source, "the leaf", p.mesh, scale, *LEAF_EXTENT)
            _LeafSheet(p, threshold)
    kinds = [p.kind for p in parts]
    where = folder or manifest or file
    if "fruit" not in kinds:
        raise MeshPlantError(entries[0]["key"], f"{where}: the plant has no fruit (put fruit "
                                                f"files in fruits/, or part: fruit)")
    if "stem" not in kinds:
        raise MeshPlantError(entries[0]["key"], f"{where}: the plant has no stem (leaves are "
                                                f"fixed at the stem nearest their petiole)")
    whole = trimesh.util.concatenate([p.mesh for p in parts])
    _CheckExtent(entries[0]["key"], where, "the plant", whole, scale, *PLANT_EXTENT)
    return parts


def TargetFruits(parts: list, mp) -> list[int]:
    """The target fruits' indices (in fruit order): ``mp.targets`` (names),
    else the manifest's ``target: true`` fruits, else every fruit."""
    fruits = [p for p in parts if p.kind == "fruit"]
    names = [p.name for p in fruits]
    if mp.targets:
        for t in mp.targets:
            if t not in names:
                raise MeshPlantError(f"{KEY}.targets", f"'{t}' is no fruit of the plant; its "
                                                       f"fruits: {', '.join(names)}")
        return [i for i, n in enumerate(names) if n in set(mp.targets)]
    marked = [i for i, p in enumerate(fruits) if p.target]
    return marked or list(range(len(fruits)))


def ValidateMeshPlant(ps) -> None:
    """Reads and checks every file of ``ps.mesh_plant`` and its targets
    (``MeshPlantError`` naming the key and file) before anything is built."""
    TargetFruits(LoadMeshPlantParts(ps.mesh_plant), ps.mesh_plant)
