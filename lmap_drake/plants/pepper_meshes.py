"""Pepper-like test meshes made by other means than the procedural family
(``lmap_drake/plants/pepper.py``), for ``scripts/eval_shape.py
--fruit_mesh_dir`` and ``plant_scene.fruit.mesh_file``:

* ``blob``: a smooth union (soft-min of signed distances) of 3-4 tilted
  ellipsoidal lobes around the axis, minus a soft stem cavity that is deep and
  off the axis; the surface is found along each direction of an icosphere by
  bisection of the implicit function (star-shaped about the centre).
* ``bent``: a superellipsoid (signed-power map of a sphere) tapered toward the
  blossom end and bent sideways by x += k z^2 (a bijection, so no
  self-intersections).
* ``sculpted``: an icosphere displaced by random Gaussian bumps and dents
  (lobes, a shoulder, a stem dent), then Taubin-smoothed.

* ``scan``: scan-like: an implicit pepper (a p-norm union of 3-5 upright
  capsule lobes around a leaning core, a stem pit cut by a soft sphere)
  warped by a random low-frequency displacement field, meshed by marching
  tetrahedra on a 1.5 mm grid (uneven triangles), with 0.15 mm vertex noise
  and a small hole punched near the blossom end (as a scanner leaves; the
  fruit-mesh loader fills it). Not in the default ``--kinds``: it was kept
  unseen during development of the template and SSC.

Each fruit gets a curved tube peduncle (``NAME.peduncle.EXT``, 1-8 cm long,
leaving the fruit 0-60 deg off its axis, capped) unless ``--no_peduncle``.
Frame: metres, +z = peduncle axis, peduncle at the top. Formats cycle through
OBJ, PLY and STL. Volumes are printed (about 40-270 cm^3).

  .venv/bin/python scripts/make_test_peppers.py --out out/test_peppers --count 6 --seed 0
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import trimesh

from lmap_drake.plants.pepper import MakePeduncle, RayHitDistance
from lmap_drake.shape.marching import MarchingTetrahedra

KINDS = ("blob", "bent", "sculpted")
FORMATS = ("obj", "ply", "stl")


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _radial_surface(f, rmax: float, subdivisions: int = 5) -> trimesh.Trimesh:
    """The zero set of ``f`` (negative inside, star-shaped about the origin)
    along each icosphere direction, by bisection in (0, rmax)."""
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    d = _unit(np.asarray(sphere.vertices, float))
    lo, hi = np.zeros(len(d)), np.full(len(d), rmax)
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        inside = f(d * mid[:, None]) < 0
        lo, hi = np.where(inside, mid, lo), np.where(inside, hi, mid)
    return trimesh.Trimesh(d * (0.5 * (lo + hi))[:, None], sphere.faces, process=True)


def Blob(rng) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Soft union of lobes minus an off-centre stem cavity; (mesh, cavity
    axis point (x, y))."""
    R = rng.uniform(0.022, 0.042)                 # lobe ring radius scale
    H = R * rng.uniform(1.6, 3.0)                 # height
    n = int(rng.integers(3, 5))
    phase = rng.uniform(0, 2 * np.pi)
    lobes = []
    for i in range(n):
        a = phase + 2 * np.pi * i / n + rng.uniform(-0.2, 0.2)
        c = 0.45 * R * np.array([np.cos(a), np.sin(a), rng.uniform(-0.1, 0.1) * H])
        ax = np.array([0.62 * R, 0.55 * R, 0.5 * H]) * rng.uniform(0.9, 1.1, 3)
        lobes.append((c, ax, _rot_z(a)))
    cav_xy = rng.uniform(-0.25, 0.25, 2) * R      # off-centre stem cavity
    cav_r = R * rng.uniform(0.3, 0.45)
    cav_c = np.array([cav_xy[0], cav_xy[1], 0.5 * H + cav_r * rng.uniform(0.1, 0.5)])

    def f(p):
        ds = []
        for c, ax, Rz in lobes:
            q = (p - c) @ Rz / ax
            ds.append((np.linalg.norm(q, axis=1) - 1.0) * ax.min())
        ds = np.stack(ds)
        k = 0.008                                   # soft-min width (m)
        d = -k * np.log(np.sum(np.exp(-ds / k), axis=0))
        cav = cav_r - np.linalg.norm(p - cav_c, axis=1)
        kk = 0.004
        return kk * np.log(np.exp(d / kk) + np.exp(cav / kk))   # soft max: subtract
    mesh = _radial_surface(f, 2.0 * H)
    return mesh, cav_xy


def Bent(rng) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Tapered, bent superellipsoid; (mesh, stem point (x, y))."""
    w = rng.uniform(0.04, 0.066)
    size = np.array([w, w * rng.uniform(0.85, 1.1), w * rng.uniform(0.9, 1.5)])
    e = rng.uniform(0.55, 0.85)                    # exponent < 1: boxy
    sphere = trimesh.creation.icosphere(subdivisions=5)
    d = _unit(np.asarray(sphere.vertices, float))
    v = np.sign(d) * np.abs(d) ** e * (0.5 * size)
    zn = v[:, 2] / (0.5 * size[2])
    taper = rng.uniform(0.1, 0.45)
    v[:, :2] *= (1.0 - taper * 0.5 * (1.0 - zn))[:, None]
    # shallow stem dent around the axis at the top
    rho = np.linalg.norm(v[:, :2], axis=1) / (0.5 * w)
    v[:, 2] -= (zn > 0) * 0.012 * rng.uniform(0.3, 1.0) * np.exp(-(rho / 0.35) ** 2)
    k = rng.uniform(-4.0, 4.0)                    # bend (1/m)
    v[:, 0] += k * v[:, 2] ** 2
    return trimesh.Trimesh(v, sphere.faces, process=True), np.zeros(2)


def Sculpted(rng) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Icosphere with random bumps and dents, smoothed; (mesh, stem (x, y))."""
    sphere = trimesh.creation.icosphere(subdivisions=5)
    d = _unit(np.asarray(sphere.vertices, float))
    r0 = rng.uniform(0.021, 0.034)
    scale = np.array([1.0, rng.uniform(0.85, 1.1), rng.uniform(0.9, 1.6)])
    r = np.ones(len(d))
    n = int(rng.integers(3, 5))
    for i in range(n):                              # lobes: bumps around the equator
        a = 2 * np.pi * i / n + rng.uniform(-0.3, 0.3)
        c = _unit(np.array([np.cos(a), np.sin(a), rng.uniform(-0.3, 0.2)]))
        r += rng.uniform(0.08, 0.16) * np.exp(-(np.arccos(np.clip(d @ c, -1, 1)) / 0.6) ** 2)
    for _ in range(int(rng.integers(3, 7))):        # random small dents and bumps
        c = _unit(rng.normal(size=3))
        r += rng.uniform(-0.06, 0.06) * np.exp(-(np.arccos(np.clip(d @ c, -1, 1)) / 0.4) ** 2)
    stem = _unit(np.array([*rng.uniform(-0.2, 0.2, 2), 1.0]))
    r -= rng.uniform(0.1, 0.25) * np.exp(-(np.arccos(np.clip(d @ stem, -1, 1)) / 0.3) ** 2)
    v = d * (r0 * r)[:, None] * scale
    mesh = trimesh.Trimesh(v, sphere.faces, process=True)
    trimesh.smoothing.filter_taubin(mesh, iterations=10)
    return mesh, np.zeros(2)


def Scan(rng) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Scan-like pepper (see the module docstring); (mesh, stem (x, y))."""
    L = rng.uniform(0.05, 0.10)                  # rough width (m)
    H = 0.5 * L * rng.uniform(0.9, 1.4)          # half height
    Rr = L * rng.uniform(0.3, 0.4)               # lobe ring radius
    n = int(rng.integers(3, 6))
    lean = rng.uniform(-0.15, 0.15, 2)           # core axis lean (x, y per z)
    rad = rng.uniform(0.6, 0.8) * Rr
    ph = rng.uniform(0, 2 * np.pi)
    lobes = [(ph + 2 * np.pi * i / n + rng.uniform(-0.25, 0.25), rad * rng.uniform(0.85, 1.15),
              H * rng.uniform(0.7, 0.95)) for i in range(n)]
    k_modes = rng.normal(size=(3, 3)) * rng.uniform(25, 60)     # 1/m
    phases = rng.uniform(0, 2 * np.pi, (3, 3))
    amp = rng.uniform(0.0015, 0.0035)
    pit = np.array([*rng.uniform(-0.2, 0.2, 2) * Rr, 0.0])
    pit_r = Rr * rng.uniform(0.35, 0.6)

    def f(p):
        q = p.copy()
        for m in range(3):                       # warp: smooth random displacement
            q[:, m] += amp * np.sin(p @ k_modes[m] + phases[m, 0])
        core = q[:, :2] - lean * q[:, 2:3]
        ds = []
        for a, r, h in lobes:
            c = Rr * 0.5 * np.array([np.cos(a), np.sin(a)])
            dz = np.clip(q[:, 2], -h + r, h - r)
            seg = np.c_[core - c, q[:, 2] - dz]
            ds.append(np.linalg.norm(seg, axis=1) - r)
        ds = np.stack(ds)
        d = -np.sum(np.maximum(-ds, 0) ** 3, axis=0) ** (1 / 3)      # p-norm union inside
        d = np.where(np.all(ds > 0, axis=0), ds.min(0), d)
        top = np.c_[core, q[:, 2]] - (pit + [0, 0, H + 0.3 * pit_r])
        cav = pit_r - np.linalg.norm(top, axis=1)
        return np.maximum(d, cav)

    lo, hi = np.full(3, -0.075), np.full(3, 0.075)
    h = 0.0015
    ax = [np.arange(lo[i], hi[i] + h / 2, h) for i in range(3)]
    grid = np.stack(np.meshgrid(*ax, indexing="ij"), -1).reshape(-1, 3)
    vals = f(grid).reshape(len(ax[0]), len(ax[1]), len(ax[2]))
    v, faces = MarchingTetrahedra(vals, lo, h)
    mesh = trimesh.Trimesh(v, faces, process=True)
    mesh = max(mesh.split(only_watertight=False), key=lambda m: abs(m.volume))
    if not (mesh.is_watertight and mesh.is_winding_consistent):
        return Scan(rng)                          # (rare) a non-manifold sample: redraw
    mesh.vertices = mesh.vertices + rng.normal(scale=0.00015, size=mesh.vertices.shape)
    # A small hole near the blossom end (a few faces of the lowest region).
    V = mesh.vertices
    low = np.argmin(V[:, 2])
    fc = mesh.triangles_center
    drop = np.argsort(np.linalg.norm(fc - V[low], axis=1))[:int(rng.integers(2, 7))]
    keep = np.ones(len(mesh.faces), bool)
    keep[drop] = False
    mesh = trimesh.Trimesh(mesh.vertices, mesh.faces[keep], process=False)
    closed = mesh.copy()
    trimesh.repair.fill_holes(closed)
    if not (closed.is_watertight and closed.is_winding_consistent):
        return Scan(rng)
    return mesh, pit[:2]


def CurvedTube(p0, angle: float, azimuth: float, length: float, radius: float,
               ring: int = 12, segments: int = 24) -> trimesh.Trimesh:
    """A capped tube from ``p0`` starting along +z and bending, as a circular
    arc, to ``angle`` (rad) off +z toward ``azimuth`` at its end (the
    plant world's peduncle tube; only the fruit bodies here are made by
    other means than the procedural family)."""
    return MakePeduncle(np.asarray(p0, float), angle, azimuth, length, radius, ring, segments)


def MakeTestPepper(kind: str, rng, peduncle: bool = True):
    """(fruit mesh, peduncle mesh or None), metres, +z peduncle axis; the
    fruit is centred on its volume centroid."""
    fruit, stem_xy = {"blob": Blob, "bent": Bent, "sculpted": Sculpted, "scan": Scan}[kind](rng)
    if kind == "scan":     # open (a scanner's hole): centre on a filled copy
        closed = fruit.copy()
        trimesh.repair.fill_holes(closed)
        c = closed.center_mass
        fruit.apply_translation(-c)
        closed.apply_translation(-c)
    else:
        fruit.apply_translation(-fruit.center_mass)
        closed = fruit
    if not peduncle:
        return fruit, None
    o = np.array([stem_xy[0], stem_xy[1], 0.0])
    t = RayHitDistance(closed, o, np.array([0.0, 0.0, 1.0]))
    if not np.isfinite(t):
        o, t = np.zeros(3), RayHitDistance(closed, np.zeros(3), np.array([0.0, 0.0, 1.0]))
    base = o + [0, 0, t - 0.004]                       # starts 4 mm inside the fruit
    ped = CurvedTube(base, np.deg2rad(rng.uniform(0, 60)), rng.uniform(0, 2 * np.pi),
                     rng.uniform(0.01, 0.08) + 0.004, rng.uniform(0.003, 0.005))
    return fruit, ped


def WriteTestPeppers(out, count: int = 6, seed: int = 0, kinds=KINDS,
                     peduncle: bool = True) -> dict:
    """``count`` test peppers (kinds in turn, formats OBJ, PLY, STL in turn)
    into the folder ``out``, with ``test_peppers.json``; prints and returns
    each file's kind, volume and extents."""
    kinds = list(kinds)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    info = {}
    for i in range(count):
        rng = np.random.default_rng(seed * 1000 + i)
        kind = kinds[i % len(kinds)]
        ext = FORMATS[i % len(FORMATS)]
        fruit, ped = MakeTestPepper(kind, rng, peduncle)
        assert kind == "scan" or (fruit.is_watertight and fruit.volume > 0), kind
        name = f"{kind}_{seed:02d}_{i:02d}"
        fruit.export(out / f"{name}.{ext}")
        if ped is not None:
            ped.export(out / f"{name}.peduncle.{ext}")
        closed = fruit.copy()
        if not closed.is_watertight:
            trimesh.repair.fill_holes(closed)
        vol = closed.volume
        info[name] = {"kind": kind, "volume_cm3": round(float(vol) * 1e6, 1),
                      "extents_cm": [round(float(x) * 100, 1) for x in fruit.extents],
                      "peduncle_length_cm": (round(float(np.linalg.norm(
                          ped.vertices.max(0) - ped.vertices.min(0))) * 100, 1)
                          if ped is not None else 0.0)}
        print(f"{name}.{ext}: {info[name]}", flush=True)
    (out / "test_peppers.json").write_text(json.dumps(info, indent=1))
    return info
