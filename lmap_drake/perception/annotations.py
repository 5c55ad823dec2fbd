"""Polygon annotations of captured views (COCO or LabelMe JSON) as class
maps with the project's label ids (``lmap_drake.labels``).

Category / label names map to classes by word: fruit (``fruit``,
``pepper``, ``capsicum``), leaf (``leaf``, ``leaves``), branch
(``branch``, ``stem``, ``stalk``, ``peduncle``); any other name is
background and listed in the result's ``ignored``. Unannotated pixels are
background. A pixel belongs to a polygon when its centre lies inside it.
Larger shapes (an annotation's polygons together) are painted first, so a
fruit drawn inside a leaf's outline stays fruit.

- COCO: one JSON with ``images`` (``id``, ``file_name``, ``width``,
  ``height``), ``annotations`` (``image_id``, ``category_id``,
  ``segmentation`` as polygon lists ``[[x1, y1, x2, y2, ...], ...]``;
  run-length masks are refused) and ``categories`` (``id``, ``name``).
- LabelMe: one JSON per image (``imagePath``, ``imageWidth``,
  ``imageHeight``, ``shapes`` with ``label``, ``points`` and
  ``shape_type`` ``polygon``; other shape types are refused).

Coordinates are pixels, x right, y down, origin at the top-left corner of
the top-left pixel (both tools' convention).
"""
from __future__ import annotations

import dataclasses as dc
import json
from pathlib import Path

import numpy as np
from matplotlib.path import Path as PolygonPath

from lmap_drake.errors import InputError
from lmap_drake.labels import BACKGROUND, BRANCH, FRUIT, LEAF

WORDS = ((FRUIT, ("fruit", "pepper", "capsicum")), (LEAF, ("leaf", "leaves")),
         (BRANCH, ("branch", "stem", "stalk", "peduncle")))


class AnnotationError(InputError):
    """An annotation file is missing, malformed or of an unsupported kind."""


@dc.dataclass
class Annotation:
    """The polygons of one image: ``image`` (its file name as annotated),
    ``width`` x ``height`` px, ``shapes`` [(class id, [(N, 2) x, y px
    polygons])] (one entry per annotated object) and the names mapped to
    background."""
    image: str
    width: int
    height: int
    shapes: list
    ignored: set = dc.field(default_factory=set)

    def ClassMap(self) -> np.ndarray:
        """HxW int64 class map (``RasterisePolygons``)."""
        return RasterisePolygons(self.shapes, self.height, self.width)

    def LeafIds(self) -> np.ndarray:
        """HxW int64: each leaf pixel's annotated object (its index in
        ``shapes``; painted in the order of ``ClassMap``), -1 elsewhere: one
        id per annotated leaf, for the leaf boundary target."""
        obj = np.full((self.height, self.width), -1, np.int64)
        for k in _PaintOrder(self.shapes):
            c, polys = self.shapes[k]
            if c != BACKGROUND:
                for p in polys:
                    obj[PolygonMask(p, self.height, self.width)] = k if c == LEAF else -1
        return obj


def NameToClass(name: str) -> int:
    """Annotation label -> class id (BACKGROUND when unrecognised)."""
    n = str(name).lower()
    for c, words in WORDS:
        if any(w in n for w in words):
            return c
    return BACKGROUND


def _Area(p: np.ndarray) -> float:
    x, y = p[:, 0], p[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1))))


def PolygonMask(poly: np.ndarray, height: int, width: int) -> np.ndarray:
    """HxW bool: the pixels whose centre (x + 0.5, y + 0.5) is inside ``poly``."""
    out = np.zeros((height, width), bool)
    if len(poly) < 3:
        return out
    x0, y0 = np.floor(poly.min(0)).astype(int).clip(0)
    x1, y1 = np.ceil(poly.max(0)).astype(int)
    x1, y1 = min(x1, width), min(y1, height)
    if x1 <= x0 or y1 <= y0:
        return out
    yy, xx = np.mgrid[y0:y1, x0:x1]
    inside = PolygonPath(poly).contains_points(np.stack([xx.ravel() + 0.5, yy.ravel() + 0.5], 1))
    out[y0:y1, x0:x1] = inside.reshape(yy.shape)
    return out


def _PaintOrder(shapes) -> list[int]:
    """Indices of ``shapes``, larger first (a stable sort)."""
    return sorted(range(len(shapes)), key=lambda k: -sum(_Area(p) for p in shapes[k][1]))


def RasterisePolygons(shapes, height: int, width: int) -> np.ndarray:
    """Class map of ``shapes`` [(class id, [(N, 2) x, y polygons])], larger
    shapes first."""
    out = np.zeros((height, width), np.int64)
    for c, polys in (shapes[k] for k in _PaintOrder(shapes)):
        if c != BACKGROUND:
            for p in polys:
                out[PolygonMask(p, height, width)] = c
    return out


def _ReadJson(path: Path, what: str) -> dict:
    if not path.is_file():
        raise AnnotationError(f"{what} {path} not found")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise AnnotationError(f"{what} {path} is not valid JSON: {err}") from None
    if not isinstance(data, dict):
        raise AnnotationError(f"{what} {path} must hold a JSON object")
    return data


def LoadLabelMe(path) -> Annotation:
    """One LabelMe JSON file (module docstring)."""
    path = Path(path)
    d = _ReadJson(path, "LabelMe file")
    try:
        ann = Annotation(str(d["imagePath"]), int(d["imageWidth"]), int(d["imageHeight"]), [])
        for k, s in enumerate(d["shapes"]):
            kind = s.get("shape_type", "polygon") or "polygon"
            if kind != "polygon":
                raise AnnotationError(f"{path}: shapes[{k}] is a {kind}; only polygons are read")
            c = NameToClass(s["label"])
            if c == BACKGROUND:
                ann.ignored.add(str(s["label"]))
            ann.shapes.append((c, [np.asarray(s["points"], float).reshape(-1, 2)]))
    except AnnotationError:
        raise
    except (KeyError, TypeError, ValueError) as err:
        raise AnnotationError(f"{path} is not a LabelMe file: {type(err).__name__}: "
                              f"{err}") from None
    return ann


def LoadCoco(path) -> dict[str, Annotation]:
    """A COCO JSON file (module docstring): {image file name: Annotation}."""
    path = Path(path)
    d = _ReadJson(path, "COCO file")
    try:
        names = {int(c["id"]): str(c["name"]) for c in d["categories"]}
        images = {int(i["id"]): Annotation(str(i["file_name"]), int(i["width"]),
                                           int(i["height"]), []) for i in d["images"]}
        for k, a in enumerate(d["annotations"]):
            seg = a["segmentation"]
            if not isinstance(seg, list):
                raise AnnotationError(f"{path}: annotations[{k}] is a run-length mask; only "
                                      f"polygons are read (export polygons)")
            ann = images[int(a["image_id"])]
            name = names[int(a["category_id"])]
            c = NameToClass(name)
            if c == BACKGROUND:
                ann.ignored.add(name)
            ann.shapes.append((c, [np.asarray(poly, float).reshape(-1, 2) for poly in seg]))
    except AnnotationError:
        raise
    except (KeyError, TypeError, ValueError) as err:
        raise AnnotationError(f"{path} is not a COCO file: {type(err).__name__}: "
                              f"{err}") from None
    return {a.image: a for a in images.values()}
