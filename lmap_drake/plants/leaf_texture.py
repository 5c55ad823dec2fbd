"""Procedural leaf textures for the greenhouse plant (``plant_scene.greenhouse.textures``).

Functional core: ``LeafTexture`` paints one leaf's texture atlas (numpy,
deterministic in the plant's seed and the leaf's index), ``LeafObjText``
writes the leaf's closed surface as OBJ text whose texture coordinates
put its upper side on the atlas' top half and its lower side on the bottom
half. ``TextureFiles`` writes both to a per-process folder for
RenderEngineVtk (``("phong", "diffuse_map")`` takes a file path;
``("deformable", "embedded_mesh")`` an OBJ path).

What the texture models, per side (leaf coordinates: u along the midrib
from the petiole base, m; v across it, m):

- a colour gradient from base to tip (paler, yellower base; darker tip);
- a lighter midrib tapering toward the tip and 6-9 pairs of lighter
  lateral veins leaving it at an angle and curving toward the tip, fading
  toward the margin;
- mottling: low-frequency noise in brightness and hue;
- the lower side greyer and darker than the upper side, its veins raised
  (stronger);
- gloss: RenderEngineVtk of Drake 1.51 reads only ``("phong", "diffuse")``
  and ``("phong", "diffuse_map")`` for OBJ meshes and primitives (no
  specular or roughness property), so the gloss of the waxy upper side is
  painted into the texture as a soft highlight band along the blade (it
  does not move with the light).

Fruits (``FruitTexture``, ``FruitObjText``): their colour with darker
shoulders, fine streaks along the axis and a painted gloss band, projected
across the fruit.

The diffuse colour of a textured geometry multiplies the texture
(RenderEngineVtk), so textured geometry is registered with a white diffuse
colour. Labels do not depend on the texture.
"""
from __future__ import annotations

import atexit
import dataclasses as dc
import hashlib
import io
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image
from scipy import ndimage

TEX_ALONG = 192          # px along the leaf (u)
TEX_ACROSS = 64          # px across the leaf (v), per side
LUMA = np.array([0.299, 0.587, 0.114])
GUTTER = 0.03            # of a half-atlas' height: kept clear of the other side's texels


@dc.dataclass
class LeafTextureImage:
    """A leaf's texture atlas ``rgb`` (H x W x 3 uint8; rows ``upper``: the
    upper side, ``lower``: the lower side) and per side the vein weight
    ``vein`` (H x W, 0-1: how much of a vein a texel is) and the leaf
    coordinates of each texel's centre (``u``, ``v``, m)."""
    rgb: np.ndarray
    vein: np.ndarray
    u: np.ndarray
    v: np.ndarray
    upper: slice
    lower: slice


def _Rng(seed: int, index: int, salt: int) -> np.random.Generator:
    return np.random.default_rng([int(seed) & 0xFFFFFFFF, int(index) & 0xFFFFFFFF, salt])


def _Field(rng, shape, sigma) -> np.ndarray:
    """Smooth noise of unit standard deviation (Gaussian-filtered white noise)."""
    f = ndimage.gaussian_filter(rng.standard_normal(shape), sigma, mode="wrap")
    return f / max(float(f.std()), 1e-9)


def LeafTexture(seed: int, index: int, color, u_range, v_half: float,
                length: float) -> LeafTextureImage:
    """The texture atlas of leaf ``index`` of the plant of ``seed``: base
    colour ``color`` (upper side, RGB(A) 0-1), leaf coordinates ``u_range``
    (min, max; u < 0 is the petiole) and ``v_half`` (m, half the widest
    extent across), blade ``length`` (m). Deterministic in its arguments."""
    rng = _Rng(seed, index, 0x7E47)
    c = np.clip(np.asarray(color, float)[:3], 0, 1)
    W, H = TEX_ALONG, TEX_ACROSS
    u0, u1 = float(u_range[0]), float(u_range[1])
    x = (np.arange(W) + 0.5) / W
    y = 1.0 - (np.arange(H) + 0.5) / H                 # +1 at the top row of a half
    y = (y - 0.5) * 2.0 / (1.0 - 2.0 * GUTTER)        # -1..1 over the used band
    u = u0 + x * (u1 - u0)
    U, Y = np.meshgrid(u, y)                           # H x W
    s = np.clip(U / max(length, 1e-6), 0.0, 1.0)
    ay = np.abs(np.clip(Y, -1.0, 1.0))
    petiole = U < 0.0

    # veins: the midrib and pairs of lateral veins curving toward the tip
    mid_w = 0.07 * (1.0 - 0.65 * s) + 0.015
    midrib = np.exp(-(Y / mid_w) ** 2)
    n_veins = int(rng.integers(6, 10))
    s0 = np.linspace(0.06, 0.88, n_veins) + rng.uniform(-0.02, 0.02, n_veins)
    slope = rng.uniform(0.28, 0.42)
    lateral = np.zeros_like(s)
    for k in range(n_veins):
        d = s - s0[k] - slope * ay ** 0.8
        width = 0.010 * (1.0 - 0.5 * ay) + 0.004
        lateral = np.maximum(lateral, np.exp(-(d / width) ** 2) * (1.0 - ay) ** 0.6
                             * (ay > 0.5 * mid_w))
    vein = np.clip(np.maximum(midrib, lateral), 0.0, 1.0)
    vein[petiole] = 1.0

    # blade colour: gradient base -> tip, mottling in brightness and hue
    grad = (1.12 - 0.24 * s)[..., None] * c + (1.0 - s)[..., None] * np.array([0.03, 0.025, -0.01])
    mottle = _Field(rng, (H, W), (3.0, 9.0))
    hue = _Field(rng, (H, W), (4.0, 12.0))

    def side(light, lum_scale, grey, vein_mid, vein_lat, mottle_amp, gloss):
        base = grad * lum_scale
        lum = (base @ LUMA)[..., None]
        base = (1.0 - grey) * base + grey * lum * np.array([1.0, 1.04, 0.93])
        base = base * (1.0 + mottle_amp * mottle)[..., None]
        base = base + 0.35 * mottle_amp * hue[..., None] * np.array([0.04, 0.06, -0.02])
        vein_col = base * 1.45 + light
        w = np.clip(vein_mid * midrib + vein_lat * lateral, 0.0, 1.0)[..., None]
        out = (1.0 - w) * base + w * vein_col
        if gloss > 0:
            y_g = rng.uniform(-0.45, 0.45)
            band = np.exp(-((Y - y_g) / 0.28) ** 2) * np.sin(np.pi * s) ** 1.5
            out = out + gloss * band[..., None] * (1.0 - out)
        petiole_col = np.clip(c * 1.25 * lum_scale + np.array([0.06, 0.09, 0.0]), 0, 1)
        out[petiole] = petiole_col
        return np.clip(out, 0.0, 1.0)

    upper = side(np.array([0.08, 0.1, 0.03]), 1.0, 0.0, 0.55, 0.32, 0.09, 0.14)
    lower = side(np.array([0.1, 0.1, 0.07]), 0.8, 0.45, 0.75, 0.5, 0.05, 0.0)
    rgb = np.round(255.0 * np.concatenate([upper, lower], axis=0)).astype(np.uint8)
    return LeafTextureImage(rgb=rgb, vein=np.concatenate([vein, vein]),
                            u=np.concatenate([U, U]), v=np.concatenate([Y, Y]) * v_half,
                            upper=slice(0, H), lower=slice(H, 2 * H))


def LeafUvBounds(uv: np.ndarray) -> tuple[tuple[float, float], float]:
    """(u range, half width) of leaf coordinates ``uv`` (N x 2, m)."""
    uv = np.asarray(uv, float)
    return (float(uv[:, 0].min()), float(uv[:, 0].max())), \
        max(float(np.abs(uv[:, 1]).max()), 1e-6)


def TexCoords(uv: np.ndarray, upper: bool) -> np.ndarray:
    """Atlas texture coordinates (OBJ ``vt``, v = 1 at the image's top row)
    of leaf coordinates ``uv`` on the upper or the lower side."""
    (u0, u1), vh = LeafUvBounds(uv)
    x = (uv[:, 0] - u0) / max(u1 - u0, 1e-9)
    y = 0.5 + 0.5 * np.clip(uv[:, 1] / vh, -1, 1) * (1.0 - 2.0 * GUTTER)   # 0..1 in a half
    t = 0.5 + 0.5 * y if upper else 0.5 * y
    return np.c_[x, t]


def _SideNormals(V, F) -> np.ndarray:
    """Area-weighted vertex normals over faces ``F`` only (0 where unused)."""
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    n = np.zeros_like(V)
    for k in range(3):
        np.add.at(n, F[:, k], fn)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return np.where(norm > 1e-15, n / np.maximum(norm, 1e-15), [0.0, 0.0, 1.0])


def LeafObjText(vertices, faces, uv, normal_W) -> str:
    """OBJ text of a leaf's closed surface (``vertices`` N x 3, ``faces`` F x
    3, leaf coordinates ``uv`` per vertex, m): faces whose normal points
    along ``normal_W`` are the upper side (atlas top half), the others the
    lower side; per side smooth normals (as two separate meshes would
    have)."""
    V = np.asarray(vertices, float)
    F = np.asarray(faces, np.int64)
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    up = fn @ np.asarray(normal_W, float) >= 0
    n = len(V)
    vt = np.r_[TexCoords(uv, True), TexCoords(uv, False)]
    vn = np.r_[_SideNormals(V, F[up]), _SideNormals(V, F[~up])]
    lines = [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in V]   # as TetMeshToVtk
    lines += [f"vt {a:.6f} {b:.6f}" for a, b in vt]
    lines += [f"vn {a:.6f} {b:.6f} {c:.6f}" for a, b, c in vn]
    off = np.where(up, 0, n)[:, None] + F + 1
    lines += [f"f {i}/{a}/{a} {j}/{b}/{b} {k}/{c}/{c}"
              for (i, j, k), (a, b, c) in zip(F + 1, off)]
    return "\n".join(lines) + "\n"


FRUIT_TEX = 96          # px, the fruit texture's side


def FruitTexture(seed: int, index: int, color) -> np.ndarray:
    """Fruit ``index``'s texture (FRUIT_TEX square, RGB uint8; u across the
    fruit, v along its axis, v = 1 at the stalk): its colour ``color`` (RGB(A)
    0-1) with a gradient along the axis (darker shoulders at the stalk, a
    paler blossom end), fine streaks along the axis and a painted gloss
    highlight (a soft vertical band: RenderEngineVtk has no specular
    property). Deterministic in its arguments."""
    rng = _Rng(seed, index, 0xF417)
    c = np.clip(np.asarray(color, float)[:3], 0, 1)
    n = FRUIT_TEX
    x = (np.arange(n) + 0.5) / n
    X, Y = np.meshgrid(x, 1.0 - x)                      # Y: 1 at the stalk (top row)
    shade = 1.0 - 0.22 * np.clip((Y - 0.6) / 0.4, 0, 1) ** 1.5 + 0.08 * (1.0 - Y)
    streak = ndimage.gaussian_filter(rng.standard_normal((n, n)), (12.0, 0.8), mode="wrap")
    streak /= max(float(streak.std()), 1e-9)
    out = c * (shade * (1.0 + 0.06 * streak))[..., None]
    x_g = rng.uniform(0.3, 0.42)
    band = np.exp(-((X - x_g) / 0.07) ** 2) * np.clip(np.sin(np.pi * (Y * 0.9 + 0.05)), 0, 1)
    out = out + 0.45 * band[..., None] * (1.0 - out)
    return np.round(255.0 * np.clip(out, 0, 1)).astype(np.uint8)


def FruitObjText(mesh, X_WO) -> str:
    """OBJ text of a fruit surface (W, m) with texture coordinates from a
    projection along the fruit frame's y axis: u across (O's x), v along
    its axis (O's z, 1 at the top); smooth vertex normals."""
    V = np.asarray(mesh.vertices, float)
    F = np.asarray(mesh.faces, np.int64)
    X = np.asarray(X_WO, float)
    p_O = (V - X[:3, 3]) @ X[:3, :3]
    lo, hi = p_O.min(axis=0), p_O.max(axis=0)
    t = (p_O - lo) / np.maximum(hi - lo, 1e-9)
    vn = _SideNormals(V, F)
    lines = [f"v {x:.7f} {y:.7f} {z:.7f}" for x, y, z in V]
    lines += [f"vt {a:.6f} {b:.6f}" for a, b in t[:, [0, 2]]]
    lines += [f"vn {a:.6f} {b:.6f} {c:.6f}" for a, b, c in vn]
    lines += [f"f {i}/{i}/{i} {j}/{j}/{j} {k}/{k}/{k}" for i, j, k in F + 1]
    return "\n".join(lines) + "\n"


def FruitTextureFiles(seed: int, index: int, color, mesh, X_WO) -> tuple[str, str]:
    """(OBJ path, PNG path) of fruit ``index``'s textured surface."""
    png = TextureFiles.Write(PngBytes(FruitTexture(seed, index, color)), ".png")
    return TextureFiles.Write(FruitObjText(mesh, X_WO), ".obj"), png


def InsideTets(vertices, tets, frac: float = 1e-3) -> np.ndarray:
    """``vertices`` each moved ``frac`` of the way toward the centroid of a
    tetrahedron it belongs to: strictly inside the tetrahedral mesh, as an
    embedded render mesh must be (Drake rejects a driven point that rounding
    puts a hair outside; ``frac`` 1e-3 moves a leaf's vertices by microns)."""
    V = np.asarray(vertices, float)
    T = np.asarray(tets, np.int64)
    owner = np.full(len(V), -1)
    owner[T.ravel()] = np.repeat(np.arange(len(T)), 4)
    out = V.copy()
    used = owner >= 0
    out[used] += frac * (V[T[owner[used]]].mean(axis=1) - V[used])
    return out


def PngBytes(rgb: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(np.asarray(rgb, np.uint8)).save(buf, format="PNG", optimize=False)
    return buf.getvalue()


class TextureFiles:
    """The folder of the textures and meshes written at scene-build time:
    one per process (``lmap_drake_textures_<pid>_*`` in the system's
    temporary folder), removed when the process exits. Files are named by
    the hash of their content and written atomically, so a file that
    exists is complete and can be reused; a crashed process leaves at most
    its own folder behind."""
    _dir: Path | None = None
    _pid: int = -1

    @classmethod
    def Folder(cls) -> Path:
        if cls._dir is None or cls._pid != os.getpid() or not cls._dir.is_dir():
            cls._dir = Path(tempfile.mkdtemp(prefix=f"lmap_drake_textures_{os.getpid()}_"))
            cls._pid = os.getpid()
            atexit.register(_Remove, cls._dir, cls._pid)
        return cls._dir

    @classmethod
    def Write(cls, data: bytes | str, suffix: str) -> str:
        """Path of a file holding ``data`` (written once per process)."""
        raw = data.encode() if isinstance(data, str) else data
        path = cls.Folder() / (hashlib.sha1(raw).hexdigest() + suffix)
        if not path.exists():
            tmp = path.with_suffix(path.suffix + f".{os.getpid()}.part")
            tmp.write_bytes(raw)
            os.replace(tmp, path)
        return str(path)


def _Remove(folder: Path, pid: int) -> None:
    if os.getpid() == pid:       # a forked child must not remove its parent's folder
        shutil.rmtree(folder, ignore_errors=True)


_FILES: dict = {}       # inputs' hash -> (OBJ path, PNG path), this process


def LeafTextureFiles(seed: int, index: int, color, vertices, faces, uv,
                     normal_W) -> tuple[str, str]:
    """(OBJ path, PNG path) of leaf ``index``'s textured surface (vertices
    and faces in W, m; ``uv`` its leaf coordinates; the blade ends at the
    largest u). Kept per process by their inputs: an episode builds its
    plant again at every grasp."""
    V = np.ascontiguousarray(vertices, float)
    F = np.ascontiguousarray(faces, np.int64)
    UV = np.ascontiguousarray(uv, float)
    key = hashlib.sha1(np.asarray([seed, index, len(V), len(F)], np.int64).tobytes()
                       + np.asarray(color, float).tobytes() + V.tobytes() + F.tobytes()
                       + UV.tobytes() + np.asarray(normal_W, float).tobytes()).hexdigest()
    paths = _FILES.get(key)
    if paths is None or not all(os.path.exists(p) for p in paths):
        (u0, u1), vh = LeafUvBounds(UV)
        tex = LeafTexture(seed, index, color, (u0, u1), vh, u1)
        png = TextureFiles.Write(PngBytes(tex.rgb), ".png")
        obj = TextureFiles.Write(LeafObjText(V, F, UV, normal_W), ".obj")
        paths = _FILES[key] = (obj, png)
    return paths
