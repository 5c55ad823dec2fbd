"""Collision checks of the LMAP planner (paper Sec. III-C-1): robot vs fruit
and deformed leaf vs fruit through the completed fruit's SDF, robot vs branch
and deformed leaf vs branch through the distance to the completed branch
mesh (Open3D ray-casting scene, batched). Margin in metres; world frame W."""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


class BranchDistance:
    """Unsigned distance (m) to a triangle mesh (the completed branch),
    batched with Open3D's RaycastingScene."""

    def __init__(self, vertices_W: np.ndarray, faces: np.ndarray):
        import open3d as o3d
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(o3d.core.Tensor(np.asarray(vertices_W, np.float32)),
                                  o3d.core.Tensor(np.asarray(faces, np.uint32)))

    def __call__(self, points_W: np.ndarray) -> np.ndarray:
        import open3d as o3d
        if len(points_W) == 0:
            return np.zeros(0)
        q = o3d.core.Tensor(np.asarray(points_W, np.float32))
        return self._scene.compute_distance(q).numpy().astype(float)


class UnionSdf:
    """Signed distance (m) to the nearest of several objects (a plant's
    fruits), from each one's SDF and box (lo, hi). An SDF is evaluated only
    at the points within ``pad`` (m) of its box; elsewhere the distance to
    the box stands in, a lower bound of at least ``pad``. So the result is
    exact wherever it is below ``pad`` (the planner's margins are 5 mm)
    and each fruit's decoder runs on its own neighbourhood only. NaN from
    an SDF stays NaN."""

    def __init__(self, sdfs: list, boxes: list, pad: float = 0.05):
        self._parts = [(sdf, np.asarray(lo, float), np.asarray(hi, float))
                       for sdf, (lo, hi) in zip(sdfs, boxes)]
        self.pad = float(pad)

    def __call__(self, points_W: np.ndarray, pad: float | None = None,
                 bound: float | None = None, anchors: DistanceAnchors | None = None
                 ) -> np.ndarray:
        """The signed distances; ``pad`` (m, at most ``self.pad``): a
        narrower band for this call (``Below``); ``bound`` (m): the parts
        with ``LowerBelow`` give their values only where below it and the
        parts before them (``LowerBelow``, with ``anchors``)."""
        pad = self.pad if pad is None else min(float(pad), self.pad)
        p = np.asarray(points_W, float).reshape(-1, 3)
        out = np.full(len(p), np.inf)
        bound = None if bound is None else np.broadcast_to(np.asarray(bound, float), (len(p),))
        for sdf, lo, hi in self._parts:
            d = np.linalg.norm(np.maximum(np.maximum(lo - p, p - hi), 0.0), axis=1)
            near = d < pad
            if near.any():
                low = None if bound is None else getattr(sdf, "LowerBelow", None)
                # (below the parts before, at a point, it must come to matter)
                if low is None:
                    d[near] = np.asarray(sdf(p[near]), float).reshape(-1)
                else:
                    extra = {} if anchors is None else {"anchors": anchors.Take(near)}
                    d[near] = np.asarray(low(p[near], np.minimum(bound[near], out[near]),
                                             **extra), float).reshape(-1)
            out = np.minimum(out, d)
        return out

    def LowerBelow(self, points_W: np.ndarray, bound,
                   anchors: DistanceAnchors | None = None) -> np.ndarray:
        """``self(points_W)`` where it is below ``bound`` (m; one value or
        one per point), a lower bound of it, at least ``bound``, elsewhere:
        the parts with ``LowerBelow`` (a ``MeshSetSdf``) skip what cannot
        come below it, also by ``anchors`` (``DistanceAnchors``, one per
        point: where each point was)."""
        return self(points_W, bound=bound, anchors=anchors)

    def Below(self, points_W: np.ndarray, bound: float) -> np.ndarray:
        """The distances where they may lie below ``bound`` (m): each SDF
        evaluated within ``bound`` + ``BELOW_SLACK`` of its fruit's box
        only, the box distance elsewhere (at least ``bound`` +
        ``BELOW_SLACK``). A check against ``bound`` (``RobotCollisionReason``)
        gets the same verdict and the same nearest distance as from
        ``__call__`` as long as no SDF beyond that band lies below
        ``bound`` (a decoder artefact: the fruit's surface is at least the
        band away there)."""
        return self(points_W, pad=bound + BELOW_SLACK, bound=bound)

    def NearestBelow(self, points_W: np.ndarray, bound: float, first_hit: bool = False
                     ) -> float:
        """The smallest of ``Below(points_W, bound)``: exact when below
        ``bound`` (m), else a value at least ``bound``; NaN when one of
        those distances is not finite. Each part gets the smallest distance
        found so far as its bound (``NearestWithin``: a ``MeshSetSdf``
        computes exact distances only where they may come below it). With
        ``first_hit``, only whether it is below ``bound``: the parts with
        ``NearestWithin`` first, and the first value below ``bound`` (not
        the smallest) is returned (a NaN behind it goes unseen)."""
        return self._Nearest(points_W, float(bound), float(bound) + BELOW_SLACK, first_hit)

    def NearestWithin(self, points_W: np.ndarray, bound: float, first_hit: bool = False
                      ) -> float:
        """``NearestBelow`` of ``self(points_W)`` (this union's own band)."""
        return self._Nearest(points_W, float(bound), self.pad, first_hit)

    def _Nearest(self, points_W: np.ndarray, bound: float, pad: float,
                 first_hit: bool = False) -> float:
        pad = min(float(pad), self.pad)
        p = np.asarray(points_W, float).reshape(-1, 3)
        best = np.inf
        parts = (sorted(self._parts, key=lambda part: not hasattr(part[0], "NearestWithin"))
                 if first_hit else self._parts)
        for sdf, lo, hi in parts:
            d = np.linalg.norm(np.maximum(np.maximum(lo - p, p - hi), 0.0), axis=1)
            near = d < pad
            if not near.all():
                best = min(best, float(d[~near].min()))
            if not near.any():
                continue
            nearest = getattr(sdf, "NearestWithin", None)
            if nearest is not None:
                v = float(nearest(p[near], min(bound, best), first_hit=first_hit))
            else:
                vals = np.asarray(sdf(p[near]), float).reshape(-1)
                if np.any(vals == np.inf):      # (another part may be finite there)
                    full = self(p, pad=pad)
                    return float(full.min()) if np.all(np.isfinite(full)) else np.nan
                v = float(vals.min()) if np.all(np.isfinite(vals)) else np.nan
            if np.isnan(v):
                return np.nan
            best = min(best, v)
            if first_hit and best < bound:
                return best
        return best


# m: how far beyond a check's margin ``UnionSdf.Below`` still evaluates the
# fruits' SDFs (the single-fruit planner evaluates none beyond the margin).
# Far from the fruit the decoder's SDF is no distance: on the three 36-45
# leaf greenhouse plants of ``scripts/bench_planner.py --plants`` (label
# oracle, first plan) it lay up to 19.6 mm below the distance to the
# fruit's box 10-50 mm beyond the margin, but never below the margin there
# (3.5 mm above it at the least), so every verdict and nearest distance was
# that of the full 5 cm band, at 54-62 % fewer decoder evaluations.
BELOW_SLACK = 0.01


class MeshSdf:
    """Signed distance (m, negative inside) to a closed triangle mesh (W),
    batched with Open3D's RaycastingScene (inside by ray parity)."""

    def __init__(self, vertices_W: np.ndarray, faces: np.ndarray):
        import open3d as o3d
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(o3d.core.Tensor(np.asarray(vertices_W, np.float32)),
                                  o3d.core.Tensor(np.asarray(faces, np.uint32)))

    def __call__(self, points_W: np.ndarray) -> np.ndarray:
        import open3d as o3d
        p = np.asarray(points_W, np.float32).reshape(-1, 3)
        if len(p) == 0:
            return np.zeros(0)
        return self._scene.compute_signed_distance(o3d.core.Tensor(p)).numpy().astype(float)


class MeshSetSdf:
    """Signed distance (m) to the union of several closed triangle meshes
    (W), for the price of about one: the unsigned distance to the nearest
    surface from one Open3D scene holding them all, the sign from each
    mesh's occupancy (ray parity, cheap). Exact outside them all; inside
    one, minus the distance to the nearest surface of any (never deeper
    than the true value, always negative)."""

    def __init__(self, meshes: list):
        import open3d as o3d
        meshes = [(np.asarray(v, np.float32), np.asarray(f, np.uint32)) for v, f in meshes
                  if len(f)]
        self._all = o3d.t.geometry.RaycastingScene()
        self._each = []
        V = [v for v, _ in meshes]
        self._lo, self._hi = ((np.vstack(V).min(0), np.vstack(V).max(0)) if V
                              else (np.zeros(3), np.zeros(3)))
        # (``_Inside``: each mesh's box top, float32 as the query points)
        self._each_hi = [(v.max(0) + OCCUPANCY_GUARD).astype(np.float32) for v, _ in meshes]
        for v, f in meshes:
            self._all.add_triangles(o3d.core.Tensor(v), o3d.core.Tensor(f))
            one = o3d.t.geometry.RaycastingScene()
            one.add_triangles(o3d.core.Tensor(v), o3d.core.Tensor(f))
            self._each.append(one)
        # for ``LowerBelow``: the vertices of a triangle (on the surface,
        # ``_surface``), each with its longest edge (a point of a triangle
        # lies within that of each of its vertices), in two groups (most,
        # and the few with long edges), each with its longest such edge
        V, R = [], []
        for v, f in meshes:
            v, f = v.astype(float), f.astype(np.int64)
            e = np.linalg.norm(v[f] - v[np.roll(f, 1, axis=1)], axis=-1)
            r = np.zeros(len(v))
            for k in range(3):          # edge k joins corners k and k - 1
                np.maximum.at(r, f[:, k], e[:, k])
                np.maximum.at(r, f[:, k - 1], e[:, k])
            used = np.unique(f)
            V.append(v[used])
            R.append(r[used])
        self._surface, self._groups = None, []
        if V:
            V, R = np.vstack(V), np.concatenate(R)
            self._surface = cKDTree(V)
            cut = 1.5 * float(np.median(R))
            self._groups = [(cKDTree(V[m]), float(R[m].max())) for m in (R <= cut, R > cut)
                            if m.any()]

    def _LowerBound(self, p: np.ndarray, bound: np.ndarray) -> np.ndarray:
        """A lower bound (m) of the distance from ``p`` (N, 3) to the
        meshes' surfaces: over each vertex group, the distance to its
        nearest vertex less the group's longest edge (the nearest surface
        point's triangle has a vertex in a group); where that exceeds
        ``bound`` (one per point) + ``MESH_BOUND_GUARD`` it may stand at
        that."""
        out = np.full(len(p), np.inf)
        for tree, r in self._groups:
            cap = bound + r + MESH_BOUND_GUARD
            d = tree.query(p, distance_upper_bound=max(float(cap.max()), 0.0))[0]
            out = np.minimum(out, np.minimum(d, cap) - r)
        return out

    def _Inside(self, q) -> np.ndarray:
        """Whether each point of ``q`` (an Open3D float32 tensor (N, 3)) is
        inside a mesh (Open3D's occupancy, each mesh's own). Open3D counts
        the crossings of a ray along about (1, 1, 1) (each component
        positive; ``tests/planning/test_collision.py`` checks it): a point
        beyond a mesh's box in any coordinate (by ``OCCUPANCY_GUARD``) has
        none, so only the others are asked (the same answer)."""
        import open3d as o3d
        p = q.numpy()
        inside = np.zeros(len(p), bool)
        for one, hi in zip(self._each, self._each_hi):
            ask = np.flatnonzero(~np.any(p > hi, axis=1))
            if len(ask) == len(p):
                inside |= one.compute_occupancy(q).numpy() > 0.5
            elif len(ask):
                inside[ask] |= one.compute_occupancy(o3d.core.Tensor(p[ask])).numpy() > 0.5
        return inside

    def __call__(self, points_W: np.ndarray) -> np.ndarray:
        import open3d as o3d
        p = np.asarray(points_W, np.float32).reshape(-1, 3)
        if len(p) == 0 or not self._each:
            return np.full(len(p), np.inf)
        q = o3d.core.Tensor(p)
        d = self._all.compute_distance(q).numpy().astype(float)
        return np.where(self._Inside(q), -d, d)

    def LowerBelow(self, points_W: np.ndarray, bound,
                   anchors: DistanceAnchors | None = None) -> np.ndarray:
        """``self(points_W)`` where it is below ``bound`` (m; one value or
        one per point); elsewhere a lower bound of it, at least ``bound``:
        ``_LowerBound`` (``MESH_BOUND_GUARD`` kept for the float32
        distances), and with ``anchors`` (``DistanceAnchors``, one per
        point) also the anchor's distance less how far the point lies from
        it, so the exact distance (Open3D's, the costly part) is computed
        only inside a mesh or where those bounds are below ``bound``. The
        same verdict and nearest distance for a check against ``bound``."""
        import open3d as o3d
        p = np.asarray(points_W, np.float32).reshape(-1, 3)
        if len(p) == 0 or not self._each:
            return np.full(len(p), np.inf)
        inside = self._Inside(o3d.core.Tensor(p))
        bound = np.broadcast_to(np.asarray(bound, float), (len(p),))
        d = self._LowerBound(p.astype(float), bound)
        if anchors is not None and id(self) in anchors.bounds:
            d = np.maximum(d, anchors.Bound(self, p))
        exact = inside | (d < bound + MESH_BOUND_GUARD)
        if exact.any():
            d[exact] = self._all.compute_distance(o3d.core.Tensor(p[exact])).numpy()
        return np.where(inside, -d, d)

    def NearestWithin(self, points_W: np.ndarray, bound: float, chunk: int = 16,
                      first_hit: bool = False) -> float:
        """The smallest of ``self(points_W)``: exact when below ``bound``
        (m), else a value at least ``bound``. Inside a mesh the exact
        distances (for the deepest: a point's distance is at most its
        nearest vertex's); outside, the exact ones only where
        ``_LowerBound`` is below ``bound`` and the smallest found so far,
        the lowest bounds first, ``chunk`` points, then four times more
        each round. ``first_hit``: a value below ``bound`` as soon as one
        is found (a point inside: -0.0)."""
        import open3d as o3d
        p = np.asarray(points_W, np.float32).reshape(-1, 3)
        if len(p) == 0 or not self._each:
            return np.inf
        inside = self._Inside(o3d.core.Tensor(p))
        best = np.inf
        if first_hit and inside.any() and bound > 0.0:
            return -0.0
        if inside.any():
            # the deepest: a vertex is on the surface, so the distance there
            # is at most the nearest vertex's, the largest first
            ins = np.flatnonzero(inside)
            up = self._surface.query(p[ins].astype(float))[0]
            order = np.argsort(-up, kind="stable")
            ins, up = ins[order], up[order]
            deepest, n = -np.inf, chunk
            while len(ins):
                d = self._all.compute_distance(o3d.core.Tensor(p[ins[:n]])).numpy()
                deepest = max(deepest, float(d.max()))
                ins, up, n = ins[n:], up[n:], 4 * n
                ins = ins[up > deepest - MESH_BOUND_GUARD]
                up = up[up > deepest - MESH_BOUND_GUARD]
            best = -deepest
        rest = np.flatnonzero(~inside)
        b = min(float(bound), best)
        if len(rest) and b + MESH_BOUND_GUARD > 0.0:
            lb = self._LowerBound(p[rest].astype(float), np.full(len(rest), b))
            keep = lb < b + MESH_BOUND_GUARD
            order = np.argsort(lb[keep], kind="stable")
            rest, lb, n = rest[keep][order], lb[keep][order], chunk
            while len(rest):
                d = self._all.compute_distance(o3d.core.Tensor(p[rest[:n]])).numpy()
                best = min(best, float(d.min()))
                if first_hit and best < bound:
                    return best
                b = min(float(bound), best)
                rest, lb, n = rest[n:], lb[n:], 4 * n
                left = int(np.searchsorted(lb, b + MESH_BOUND_GUARD, side="left"))
                rest, lb = rest[:left], lb[:left]
        return best if best < bound else float(bound)

    def Unsigned(self, points_W: np.ndarray, reach: float = 0.1) -> np.ndarray:
        """A lower bound (m) of the unsigned distance from ``points_W`` to
        the meshes' surfaces: Open3D's distance within ``reach`` (m) of the
        meshes' box, the distance to that box farther out."""
        import open3d as o3d
        p = np.asarray(points_W, np.float32).reshape(-1, 3)
        out = np.linalg.norm(np.maximum(np.maximum(self._lo - p, p - self._hi), 0.0), axis=1)
        near = out < reach
        if near.any() and self._each:
            out[near] = self._all.compute_distance(o3d.core.Tensor(p[near])).numpy()
        return out.astype(float)

    def AnyNearer(self, points_W: np.ndarray, bound: float) -> bool:
        """Whether a point of ``points_W`` surely lies nearer than ``bound``
        (m) to a mesh's surface (inside or out): nearer than ``bound`` to
        a vertex (on the surface). A cheap sufficient test (False: not
        found so)."""
        p = np.asarray(points_W, np.float32).reshape(-1, 3)
        if not self._each or bound <= 0.0:
            return False
        p = p[np.all((p >= self._lo - bound) & (p <= self._hi + bound), axis=1)]
        return bool(len(p)) and bool(np.any(
            self._surface.query(p.astype(float), distance_upper_bound=bound)[0] < bound))


class DistanceAnchors:
    """Where points were (``points_W`` (N, 3), e.g. a leaf at rest) and,
    for each ``MeshSetSdf`` inside a fruit SDF (``UnionSdf`` parts), a
    lower bound of its unsigned distance there (``MeshSetSdf.Unsigned``).
    A distance is 1-Lipschitz: a point s (m) from its anchor is at least
    the anchor's distance less s from the meshes (``Bound``), which spares
    ``MeshSetSdf.LowerBelow`` Open3D's exact distance where that is
    already beyond its bound (a moved leaf: most of it far from a fruit)."""

    def __init__(self, sdf, points_W: np.ndarray):
        self.points_W = np.asarray(points_W, np.float32).reshape(-1, 3).astype(float)
        self.bounds = {id(m): m.Unsigned(self.points_W) for m in MeshSets(sdf)}

    def Take(self, sel) -> "DistanceAnchors":
        """The anchors of the points ``sel`` (a mask or indices)."""
        out = DistanceAnchors.__new__(DistanceAnchors)
        out.points_W = self.points_W[sel]
        out.bounds = {k: v[sel] for k, v in self.bounds.items()}
        return out

    def Bound(self, mesh_set: "MeshSetSdf", points_W: np.ndarray) -> np.ndarray:
        """A lower bound (m) of ``mesh_set``'s unsigned distance at
        ``points_W`` (one per anchor, float32 as Open3D sees them), less
        ``MESH_BOUND_GUARD`` for Open3D's float32 distances."""
        p = np.asarray(points_W, np.float32).reshape(-1, 3).astype(float)
        return (self.bounds[id(mesh_set)] - np.linalg.norm(p - self.points_W, axis=1)
                - MESH_BOUND_GUARD)


def MeshSets(sdf) -> list:
    """The ``MeshSetSdf`` parts of a fruit SDF (itself, or inside ``UnionSdf``s)."""
    if isinstance(sdf, MeshSetSdf):
        return [sdf]
    if isinstance(sdf, UnionSdf):
        return [m for part, _, _ in sdf._parts for m in MeshSets(part)]
    return []


# m: ``MeshSetSdf._Inside`` asks Open3D's occupancy of the points not beyond
# a mesh's box by more than this (its rays start at the point).
OCCUPANCY_GUARD = 1e-4

# m: ``MeshSetSdf.LowerBelow`` computes the exact distance wherever its bound
# is below the check's bound plus this (Open3D's distances are float32).
MESH_BOUND_GUARD = 1e-5


def FruitSetSdf(fruit, pad: float = 0.05):
    """(sdf, (lo, hi)): the signed distance (m) to the union of a
    ``FruitEstimate`` and its kept shape hypotheses (``fruit.hypotheses``;
    the estimate's own SDF, the other hypotheses' meshes together through
    ``MeshSetSdf``) and the box of them all: clearance checked against it
    holds for every shape the view leaves plausible. Without hypotheses,
    the estimate's SDF and box."""
    box = (fruit.vertices_W.min(0), fruit.vertices_W.max(0))
    hyp = getattr(fruit, "hypotheses", None)
    meshes = ([(v, f) for v, f in zip(hyp.vertices_W[1:], hyp.faces[1:]) if len(f)]
              if hyp is not None else [])             # 0 is the estimate
    if not meshes:
        return fruit.sdf_W, box
    V = np.vstack([v for v, _ in meshes])
    sdfs, boxes = [fruit.sdf_W, MeshSetSdf(meshes)], [box, (V.min(0), V.max(0))]
    lo = np.min([b[0] for b in boxes], axis=0)
    hi = np.max([b[1] for b in boxes], axis=0)
    return UnionSdf(sdfs, boxes, pad), (lo, hi)


def NearBox(points_W, lo: np.ndarray, hi: np.ndarray, geometries=None) -> np.ndarray:
    """Points inside the axis-aligned box [lo, hi] (a cheap pre-filter).
    ``points_W``: an (N, 3) array, or the robot's samples per geometry
    (``robot_model.SurfaceSamples``): then only the geometries whose world
    box meets [lo, hi] are transformed and filtered (the same points, the
    others cannot lie inside; a UR5 pose has about 13 000 samples and
    usually one or two geometries near the plant). ``geometries`` (a bool
    per geometry, for ``SurfaceSamples`` only): only those are looked at."""
    boxes = getattr(points_W, "boxes", None)
    if boxes is not None:
        inside = np.all((boxes[:, 0] <= hi) & (boxes[:, 1] >= lo), axis=1)
        if geometries is not None:
            inside &= np.asarray(geometries, bool)
        meets = np.flatnonzero(inside)
        if len(meets) == 0:
            return np.zeros((0, 3))
        points_W = np.vstack([points_W[int(i)] for i in meets])
    return points_W[np.all((points_W >= lo) & (points_W <= hi), axis=1)]


def AllPoints(points_W) -> np.ndarray:
    """(N, 3): ``points_W`` itself, or a ``SurfaceSamples``' geometries stacked."""
    return np.vstack(list(points_W)) if hasattr(points_W, "boxes") else points_W


def RobotCollisionReason(robot_points_W: np.ndarray, fruit_sdf, branch_distance,
                         margin: float, fruit_box=None, branch_box=None,
                         body_fruit_margin: float | None = None,
                         verdict_only: bool = False) -> str:
    """'' if the robot samples keep ``margin`` from the fruit (SDF) and the
    branch mesh, else the reason. ``robot_points_W``: (N, 3) world points or
    a ``SurfaceSamples`` (per geometry, see ``NearBox``). ``*_box`` = (lo,
    hi) bounds of each object; only samples within ``margin`` of those
    bounds are queried. ``body_fruit_margin`` (m, with ``SurfaceSamples``):
    the geometries not on the fingers keep this from the fruit instead
    (when larger than ``margin``; the reason then reads 'robot-body-fruit').
    ``verdict_only``: the same verdict and reason up to its parenthesis
    (a plant's fruits (``UnionSdf``): the first distance below the
    margin found, not the nearest: ``NearestBelow``'s ``first_hit``)."""
    checks = [("fruit", "fruit", fruit_sdf, fruit_box, margin, None)]
    fingers = getattr(robot_points_W, "fingers", None)
    if (body_fruit_margin is not None and fingers is not None and np.isfinite(margin)
            and body_fruit_margin > margin):
        checks = [("fruit", "fruit", fruit_sdf, fruit_box, margin, fingers),
                  ("fruit", "body-fruit", fruit_sdf, fruit_box, body_fruit_margin, ~fingers)]
    checks.append(("branch", "branch", branch_distance, branch_box, margin, None))
    for name, what, distance, box, m, geoms in checks:
        if distance is None:
            continue
        if box is None and geoms is None:
            pts = AllPoints(robot_points_W)
        else:                   # (no box: an unbounded one, to pick the geometries)
            lo, hi = box if box is not None else (np.full(3, -np.inf), np.full(3, np.inf))
            pts = NearBox(robot_points_W, lo - m, hi + m, geoms)
        if len(pts):
            nearest = getattr(distance, "NearestBelow", None)   # a plant's fruits: one band
            if nearest is not None and np.isfinite(m):
                # the nearest of ``Below``'s distances (exact below ``m``)
                d_min = float(nearest(pts, m, first_hit=verdict_only))
                if not np.isfinite(d_min):
                    return f"robot-{name} (non-finite {name} distance)"
                if d_min < m:
                    return (f"robot-{what} (verdict only)" if verdict_only
                            else f"robot-{what} ({d_min * 1000:.1f} mm)")
                continue
            below = getattr(distance, "Below", None)
            d = np.asarray(distance(pts) if below is None else below(pts, m), float)
            if np.isfinite(m) and not np.all(np.isfinite(d)):
                # NaN passes every comparison: a non-finite distance rejects.
                return f"robot-{name} (non-finite {name} distance)"
            if d.min() < m:
                return f"robot-{what} ({d.min() * 1000:.1f} mm)"
    return ""


def LeafCollisionReason(rest_W: np.ndarray, deformed_W: np.ndarray, distance,
                        margin: float, box=None, rest_distance=None, what: str = "fruit",
                        ignore_touching: bool = False,
                        anchors: DistanceAnchors | None = None) -> str:
    """'' unless a leaf point ends within ``margin`` of an object (or inside
    it) after moving toward it: ``distance`` maps (N, 3) points to the
    object's signed (the fruit's SDF) or unsigned (``BranchDistance``)
    distance, ``what`` names it in the reason. Leaf points that already rest
    that close and do not approach are not counted (a leaf lying on its
    fruit is not a collision caused by the action); with
    ``ignore_touching`` points resting within ``margin`` are not counted at
    all (the petiole's base at the branch it grows from). ``box`` (lo, hi):
    only deformed points within ``margin`` of it are evaluated (the others
    are farther than ``margin`` from the object); ``rest_distance``: the
    distance at ``rest_W``, when already known (one evaluation for many
    actions); ``anchors``: ``DistanceAnchors`` at ``rest_W`` (the same
    verdict, fewer exact mesh distances)."""
    if distance is None or deformed_W is None or len(deformed_W) == 0:
        return ""
    deformed_W = np.asarray(deformed_W, float)
    sel = np.ones(len(deformed_W), bool)
    if box is not None:
        lo, hi = np.asarray(box[0]) - margin, np.asarray(box[1]) + margin
        sel = np.all((deformed_W >= lo) & (deformed_W <= hi), axis=1)
        if not sel.any():
            return ""
    # exact where below the margin, a lower bound at least the margin
    # elsewhere (``LowerBelow``): the same verdict and nearest distance
    d0 = (np.asarray(rest_distance, float)[sel] if rest_distance is not None
          else np.asarray(distance(np.asarray(rest_W)[sel]), float))
    low = getattr(distance, "LowerBelow", None)
    extra = {} if anchors is None or low is None else {"anchors": anchors.Take(sel)}
    d1 = np.asarray(distance(deformed_W[sel]) if low is None else
                    low(deformed_W[sel], np.minimum(margin, np.nan_to_num(d0, nan=margin)
                                                    - 1e-3), **extra), float)
    if not (np.all(np.isfinite(d1)) and np.all(np.isfinite(d0))):
        return f"leaf-{what} (non-finite {what} distance)"
    bad = (d1 < margin) & (d1 < d0 - 1e-3)
    if ignore_touching:
        bad &= d0 >= margin
    if bad.any():
        return f"leaf-{what} ({d1[bad].min() * 1000:.1f} mm)"
    return ""
