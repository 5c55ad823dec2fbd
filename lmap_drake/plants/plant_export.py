"""Writes a generated plant (``plant_scene.kind: greenhouse``, or any
``MultiPlantModel`` with ``static_leaves``) as a plant folder that
``plant_scene.kind: mesh_plant`` reads (``scripts/export_plant.py``):

    plant.yaml            manifest: every file with its part type, colours, targets
    stems/stem_<s>.obj    the stems and the fruits' side shoots (tubes)
    stems/stalk_<i>.obj   fruit i's stalk (and curved peduncle)
    leaves/leaf_<jj>.obj  each leaf's mid-surface (open sheet), in the plant's
                          leaf order (its FEM leaves first); with ``cards``:
                          a flat textured quad + .mtl + .png whose alpha is
                          the leaf's outline, as plant-modelling tools export
    fruits/fruit_<i>.obj  each fruit's closed surface
    export_info.json      the source scenario's plant ground truth and the
                          ``X_W_plant`` that puts the files back in place

Frame of the files: metres, z up, origin at the plant's
``plant_scene.p_W_branch_base`` (so ``mesh_plant.X_W_plant`` with that
translation restores the plant where it was generated).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import trimesh
import yaml
from PIL import Image, ImageDraw
from pydrake.common.yaml import yaml_dump_typed

from lmap_drake.errors import InputError
from lmap_drake.outputs import OutputFolder
from lmap_drake.plants.config import PlantSceneConfig
from lmap_drake.plants.multi_geometry import BranchTube
from lmap_drake.plants.plant_station import GetPlantModel

CARD_SIDE = 256          # px, a card texture's longer side


def _Tuple(c) -> list:
    c = c.rgba if hasattr(c, "rgba") else c
    return [round(float(x), 4) for x in c]


def MidSurface(surface: trimesh.Trimesh) -> trimesh.Trimesh:
    """The mid-layer sheet of a two-layer leaf slab's closed surface (its
    vertices are the three layers' nodes in order, as ``MultiLeaf.Surface``
    keeps them): the top sheet's triangles on the middle layer."""
    V, F = np.asarray(surface.vertices), np.asarray(surface.faces)
    n = len(V) // 3
    top = F[(F >= 2 * n).all(1)] - n
    m = trimesh.Trimesh(V, top, process=False)
    m.remove_unreferenced_vertices()
    return m


def CardOf(sheet: trimesh.Trimesh, color) -> tuple[trimesh.Trimesh, np.ndarray, Image.Image]:
    """A flat card (2 triangles) in the sheet's best-fit plane covering it,
    its texture uv (4, 2) and an RGBA texture: the leaf colour with a paler
    midrib, alpha 255 inside the sheet's outline, 0 outside."""
    V = np.asarray(sheet.vertices)
    c = V.mean(0)
    _, _, Vt = np.linalg.svd(V - c, full_matrices=False)
    e1, e2 = Vt[0], Vt[1]
    xy = np.c_[(V - c) @ e1, (V - c) @ e2]
    lo, hi = xy.min(0), xy.max(0)
    pad = 0.03 * (hi - lo).max()
    lo, hi = lo - pad, hi + pad
    size = hi - lo
    w = CARD_SIDE if size[0] >= size[1] else max(8, int(CARD_SIDE * size[0] / size[1]))
    h = CARD_SIDE if size[1] > size[0] else max(8, int(CARD_SIDE * size[1] / size[0]))
    corners = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    quad = trimesh.Trimesh(c + corners[:, :1] * e1 + corners[:, 1:] * e2,
                           [[0, 1, 2], [0, 2, 3]], process=False)
    uv = (corners - lo) / size
    rgb = tuple(int(255 * x) for x in _Tuple(color)[:3])
    img = Image.new("RGBA", (w, h), rgb + (0,))
    draw = ImageDraw.Draw(img)
    px = np.c_[(xy[:, 0] - lo[0]) / size[0] * w, (1 - (xy[:, 1] - lo[1]) / size[1]) * h]
    for f in np.asarray(sheet.faces):
        draw.polygon([tuple(px[k]) for k in f], fill=rgb + (255,))
    # a paler midrib along the main axis, inside the leaf only
    a = np.asarray(img)
    mid = np.abs(np.arange(h) - ((0 - lo[1]) / size[1]) * h)
    rib = (mid < max(1.0, 0.015 * h))[::-1, None] & (a[..., 3] > 0)
    a = a.copy()
    a[rib, :3] = np.clip(a[rib, :3].astype(int) + 40, 0, 255)
    return quad, uv, Image.fromarray(a, "RGBA")


def WriteCardObj(path: Path, quad: trimesh.Trimesh, uv: np.ndarray, image: Image.Image) -> None:
    """OBJ + MTL + PNG of a textured card (``path`` the .obj)."""
    stem = path.stem
    lines = [f"mtllib {stem}.mtl", f"o {stem}", "usemtl leaf"]
    lines += [f"v {x:.7g} {y:.7g} {z:.7g}" for x, y, z in quad.vertices]
    lines += [f"vt {u:.6g} {v:.6g}" for u, v in uv]
    lines += [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in np.asarray(quad.faces) + 1]
    path.write_text("\n".join(lines) + "\n")
    path.with_suffix(".mtl").write_text(f"newmtl leaf\nKa 0 0 0\nKd 1 1 1\nKs 0 0 0\n"
                                        f"map_Kd {stem}.png\n")
    image.save(path.with_suffix(".png"))


def ExportPlantFolder(model, base_W, folder: str | Path, cards: bool = False,
                      info: dict | None = None) -> dict:
    """Writes ``model`` (a ``GreenhousePlantModel``) into ``folder`` (which
    must exist) in the layout of the module docstring, the files' origin at
    ``base_W`` (m, W). Returns the manifest."""
    folder = Path(folder)
    for sub in ("stems", "leaves", "fruits"):
        (folder / sub).mkdir(parents=True, exist_ok=True)
    base = np.asarray(base_W, float)
    parts = []

    def put(mesh: trimesh.Trimesh, rel: str, part: str, **extra) -> None:
        m = mesh.copy()
        m.apply_translation(-base)
        m.export(folder / rel, include_normals=False)
        parts.append(dict(file=rel, part=part, **extra))
    for b, br in enumerate(model.branches):
        put(BranchTube(br), f"stems/stem_{b}.obj", "stem")
    for i, f in enumerate(model.fruits):
        a, e = np.asarray(f.stalk_W[0], float), np.asarray(f.stalk_W[1], float)
        d = (e - a) / max(float(np.linalg.norm(e - a)), 1e-9)
        pieces = [trimesh.creation.cylinder(f.stalk_radius, segment=[a - 0.002 * d,
                                                                      e + 0.002 * d])]
        if f.peduncle_mesh_W is not None:
            pieces.append(f.peduncle_mesh_W)
        put(trimesh.util.concatenate(pieces), f"stems/stalk_{i}.obj", "stem")
    colors = [c[0] for c in model.leaf_colors] + [s.color for s in model.static_leaves]
    surfaces = model.AllLeafSurfaces()
    for j, (surf, color) in enumerate(zip(surfaces, colors)):
        sheet = MidSurface(surf)
        rel = f"leaves/leaf_{j:02d}.obj"
        if cards:
            quad, uv, img = CardOf(sheet, color)
            quad.apply_translation(-base)
            WriteCardObj(folder / rel, quad, uv, img)
            parts.append(dict(file=rel, part="leaf"))
        else:
            put(sheet, rel, "leaf", color=_Tuple(color))
    targets = set(getattr(model, "targets", []))
    for i, f in enumerate(model.fruits):
        put(f.mesh_W, f"fruits/fruit_{i}.obj", "fruit", color=_Tuple(f.color),
            target=i in targets)
    manifest = {"scale": 1.0, "up_axis": "z", "parts": parts}
    header = ("# A plant for plant_scene.kind: mesh_plant (docs/how-to/bring-your-own-plant.md)"
              "\n# written by scripts/export_plant.py; metres, z up, origin at the plant's base\n")
    (folder / "plant.yaml").write_text(header + yaml.safe_dump(manifest, sort_keys=False,
                                                               default_flow_style=None))
    gt = model.GroundTruthDict()
    (folder / "export_info.json").write_text(json.dumps(
        dict(info or {}, X_W_plant_translation=base.tolist(), cards=cards,
             num_leaves=len(surfaces), num_fem_leaves=len(model.leaves), ground_truth=gt),
        indent=1))
    return manifest


def ExportScenarioPlant(scenario, out, cards: bool = False, overwrite: bool = False) -> Path:
    """Generates the plant of ``scenario`` (``plant_scene.kind: greenhouse``)
    and writes it as a plant folder ``out`` (complete or absent: written
    aside and renamed into place). Returns the folder."""
    if scenario.plant_scene.kind != "greenhouse":
        raise InputError(f"export_plant needs plant_scene.kind: greenhouse, got "
                         f"{scenario.plant_scene.kind}")
    model = GetPlantModel(scenario)
    folder = OutputFolder(out, overwrite=overwrite, command="export_plant")
    with folder as tmp:
        ExportPlantFolder(model, scenario.plant_scene.p_W_branch_base, tmp, cards=cards,
                          info={"plant_scene": yaml_dump_typed(scenario.plant_scene,
                                                               schema=PlantSceneConfig)})
    return folder.final
