"""Sweet-pepper-like watertight meshes (metres, canonical frame: centroid at
the origin, peduncle along +z)."""
from __future__ import annotations

import numpy as np
import trimesh


def MakePepperMesh(size=(0.075, 0.075, 0.085), lobes: int = 4,
                   lobe_depth: float = 0.08, subdivisions: int = 4) -> trimesh.Trimesh:
    """A star-shaped lobed ellipsoid: an icosphere displaced radially, so it
    is watertight by construction. ``size`` is the full extent (x, y, z)."""
    if lobes < 0 or not 0.0 <= lobe_depth < 0.5:
        raise ValueError("lobes must be >= 0 and lobe_depth in [0, 0.5)")
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    d = sphere.vertices / np.linalg.norm(sphere.vertices, axis=1, keepdims=True)
    a, b, c = (0.5 * s for s in size)
    r = 1.0 / np.sqrt((d[:, 0] / a) ** 2 + (d[:, 1] / b) ** 2 + (d[:, 2] / c) ** 2)
    phi = np.arctan2(d[:, 1], d[:, 0])
    equator = 1.0 - d[:, 2] ** 2
    r = r * (1.0 - lobe_depth * 0.5 * (1.0 - np.cos(lobes * phi)) * equator)
    # Shoulders near the peduncle are flatter, the blossom end slightly tapered.
    r = r * (1.0 - 0.12 * np.clip(d[:, 2], 0, 1) ** 6 - 0.06 * np.clip(-d[:, 2], 0, 1) ** 2)
    mesh = trimesh.Trimesh(vertices=d * r[:, None], faces=sphere.faces, process=True)
    mesh.apply_translation(-mesh.center_mass)
    return mesh


def MeshToObjText(mesh: trimesh.Trimesh) -> str:
    """Wavefront OBJ text of a triangle mesh with per-vertex normals."""
    v = "\n".join(f"v {x:.7f} {y:.7f} {z:.7f}" for x, y, z in mesh.vertices)
    n = "\n".join(f"vn {x:.6f} {y:.6f} {z:.6f}" for x, y, z in mesh.vertex_normals)
    f = "\n".join(f"f {i + 1}//{i + 1} {j + 1}//{j + 1} {k + 1}//{k + 1}"
                  for i, j, k in mesh.faces)
    return v + "\n" + n + "\n" + f + "\n"
