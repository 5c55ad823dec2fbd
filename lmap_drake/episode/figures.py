"""Pictures of an episode: RGB with the segmentation overlaid (before and
after), the chosen action with the predicted deformation, and the initial
and final shape estimates against the ground truth (matplotlib PNGs).
The shape-completion table's case figures are in ``evaluation.figures``."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from lmap_drake.episode.figure_layout import (GroundTruthFocus, InstanceEdges, MaskAnchor,
                                              MaskBox, Outline, PlaceLabels, PointsBox, TextBox)
from lmap_drake.labels import BRANCH, CLASS_NAMES, FRUIT, LEAF
from lmap_drake.perception.points import ProjectPoints
from lmap_drake.viz import PNG_COMPRESS_LEVEL, RgbArray, SavePng


# Colours that stand out from green leaves and red / yellow / green fruit.
OVERLAY_COLORS = {BRANCH: (0, 170, 255), LEAF: (255, 225, 0), FRUIT: (255, 0, 200)}


def Overlay(rgb, class_map: np.ndarray, alpha: float = 0.5, title: str = "",
            instance_map: np.ndarray | None = None, focus: list | None = None) -> np.ndarray:
    """The RGB image, desaturated, with each segmented class (a HxW map of
    ``lmap_drake.labels`` ids) tinted in a contrasting colour and outlined,
    and a legend: a glance shows what the segmenter found.

    Dense plants: ``instance_map`` (the segmenter's instances) outlines every
    instance, so touching leaves stay apart; ``focus`` (dicts ``mask``,
    ``text``, ``color``, ``kind``: ``figure_layout.GroundTruthFocus``) fades
    the other segments and draws each focus mask thick in its colour with
    its label, the labels placed apart from each other and the legend."""
    from PIL import ImageDraw
    from scipy import ndimage
    base = RgbArray(rgb).astype(float)
    grey = base.mean(axis=2, keepdims=True)
    base = 0.5 * base + 0.5 * grey
    cls = np.asarray(class_map)
    a_cls = 0.2 if focus else alpha
    edges = (InstanceEdges(cls, instance_map) if instance_map is not None
             else np.zeros(cls.shape, bool))
    for c, color in OVERLAY_COLORS.items():
        m = cls == c
        if not m.any():
            continue
        base[m] = (1 - a_cls) * base[m] + a_cls * np.asarray(color, float)
        edge = (m & ~ndimage.binary_erosion(m)) | (m & edges)
        base[edge] = (0.6 * np.asarray(color, float) + 0.4 * base[edge]) if focus else color
    for f in focus or ():
        m = np.asarray(f["mask"], bool)
        base[m] = 0.55 * base[m] + 0.45 * np.asarray(f["color"], float)
        base[Outline(m, 2)] = f["color"]
    img = Image.fromarray(np.clip(base, 0, 255).astype(np.uint8))
    draw = ImageDraw.Draw(img)
    legend = ([(title, (255, 255, 255))] if title else []) + [
        (CLASS_NAMES[c], OVERLAY_COLORS[c]) for c in (BRANCH, LEAF, FRUIT)]
    if focus:
        legend.append(("thick: target fruits and the leaves hiding them (ground truth)",
                       (255, 255, 255)))
    taken = _Legend(draw, legend)
    if focus:
        texts = [f["text"] for f in focus]
        boxes = [MaskBox(np.asarray(f["mask"], bool)) for f in focus]   # labels off the masks
        corners = PlaceLabels([MaskAnchor(np.asarray(f["mask"], bool)) for f in focus],
                              [TextBox(t) for t in texts], cls.shape,
                              taken + [b for b in boxes if b is not None])
        for f, t, (u, v) in zip(focus, texts, corners):
            w, h = TextBox(t)
            draw.line([(u + w / 2, v + h / 2), MaskAnchor(np.asarray(f["mask"], bool))],
                      fill=f["color"], width=1)
            draw.rectangle([u, v, u + w, v + h], fill=(0, 0, 0), outline=f["color"])
            draw.text((u + 3, v + 1), t, fill=f["color"])
    return np.asarray(img)


def _Legend(draw, lines, x: int = 4, y: int = 4) -> list[tuple]:
    """Draws ``lines`` ((text, colour)) on black boxes from (x, y) down;
    returns the boxes (u0, v0, u1, v1) the legend covers."""
    boxes = []
    for text, color in lines:
        box = (x, y, x + 7 * len(text) + 6, y + 13)
        draw.rectangle(box, fill=(0, 0, 0))
        draw.text((x + 3, y + 1), text, fill=color)
        boxes.append(box)
        y += 16
    return boxes


def _Focus(result, images) -> list:
    """The ground-truth focus of a simulated view (``GroundTruthFocus``): the
    target fruits of the plant model and the leaves hiding them; none on
    hardware or for a plant without targets."""
    model = getattr(result.world, "model", None)
    fruits = getattr(model, "fruits", None)
    if not fruits or getattr(result.world, "hardware", False):
        return []
    targets = getattr(model, "targets", None) or range(len(fruits))
    occ = {int(i): list(getattr(fruits[i], "occluders", []) or []) for i in targets}
    return GroundTruthFocus(images["label_image"].data, occ)


def _EpisodeSegmenter(result):
    """The episode's own segmenter (the Perception system's), so the
    overlays show what the pipeline saw."""
    try:
        return result.world.diagram.GetSubsystemByName("perception").segmenter
    except Exception:  # a diagram without the perception stage
        from lmap_drake.perception.points import Intrinsics
        from lmap_drake.perception.segmentation import MakeSegmenter
        s = result.world.scenario
        return MakeSegmenter(s.perception, Intrinsics.FromCameraConfig(s.cameras["camera0"]))


def _EqualAxes(ax) -> None:
    """Same scale on x, y and z (metres)."""
    lims = np.array([ax.get_xlim3d(), ax.get_ylim3d(), ax.get_zlim3d()])
    c, r = lims.mean(axis=1), 0.5 * np.ptp(lims, axis=1).max()
    ax.set_xlim3d(c[0] - r, c[0] + r)
    ax.set_ylim3d(c[1] - r, c[1] + r)
    ax.set_zlim3d(c[2] - r, c[2] + r)
    ax.set_box_aspect((1, 1, 1))


def SaveForceFigure(trace: list, pull_limit: float, retreat_limit: float, stops: list,
                    path: Path) -> bool:
    """``wrist_force.png``: the force guard's reading over the episode, the
    wrist force's rise (N) while held leaves moved (``pull``: above its value
    at the pre-grasp pose) and backing out of the plant (``retreat``: above
    its value as the retreat began), with the limits and the stops. False
    (nothing written) without a reading."""
    if not trace:
        return False
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    t = np.array([x[0] for x in trace], float)
    rise = np.array([x[1] for x in trace], float)
    phase = np.array([x[2] for x in trace])
    fig, ax = plt.subplots(figsize=(8, 3.2))
    for name, color, limit in (("pull", "tab:blue", pull_limit),
                               ("retreat", "tab:orange", retreat_limit)):
        m = phase == name
        if m.any():
            # one line per guarded motion: a gap of more than 0.1 s splits them
            idx = np.flatnonzero(m)
            runs = np.split(idx, np.flatnonzero(np.diff(t[idx]) > 0.1) + 1)
            for k, run in enumerate(runs):
                ax.plot(t[run], rise[run], color=color, lw=1.5,
                        label=f"{name} (limit {limit:g} N)" if k == 0 else None)
        if limit > 0 and m.any():
            ax.axhline(limit, color=color, ls="--", lw=1)
    for s in stops:
        ax.axvline(float(s["t"]), color="red", lw=1)
        ax.annotate(f"stop {float(s['rise_N']):.1f} N", (float(s["t"]), float(s["rise_N"])),
                    color="red", fontsize=8, xytext=(4, 4), textcoords="offset points")
    ax.set_xlabel("simulated / episode time (s)")
    ax.set_ylabel("wrist force rise (N)")
    ax.set_title("force guard: the wrist force above its value before the grasp (pull) "
                 "and the retreat")
    ax.legend(loc="upper left", fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100, pil_kwargs={"compress_level": PNG_COMPRESS_LEVEL})
    plt.close(fig)
    return True


def SaveEpisodeFigures(result, out: Path) -> list[str]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    st0 = result.status
    planner = result.world.scenario.planner
    if SaveForceFigure(getattr(st0, "force_trace", []), planner.max_pull_force,
                       planner.max_retreat_force, getattr(st0, "force_stops", []),
                       out / "wrist_force.png"):
        files.append("wrist_force.png")
    segmenter = _EpisodeSegmenter(result)
    for tag, images in (("before", result.images_before), ("after", result.images_after)):
        if images is None or images["rgb_image"].width() == 0 or (
                tag == "after" and len(getattr(result, "views", ())) < 2):
            continue
        seg = segmenter.Segment(images["rgb_image"].data, images["depth_image"].data,
                                images["label_image"].data)
        SavePng(Overlay(images["rgb_image"], seg.class_map,
                        title=f"segmenter: {segmenter.name} ({tag})",
                        instance_map=seg.instance_map, focus=_Focus(result, images)),
                out / f"rgb_{tag}_segmented.png")
        files.append(f"rgb_{tag}_segmented.png")
    st = result.status
    model = getattr(result.world, "model", None)     # ground truth: simulation only
    plan = st.plan
    if getattr(result, "views", ()) and plan is not None:
        from lmap_drake.perception.points import Intrinsics
        cam = result.world.scenario.cameras["camera0"]
        SavePng(PlanOnImage(result.views[0].rgb, plan, st.initial_estimate,
                            Intrinsics.FromCameraConfig(cam),
                            cam.X_PB.GetDeterministicValue().GetAsMatrix4()),
                out / "plan_on_image.png")
        files.append("plan_on_image.png")
    if getattr(st, "targets", None) or hasattr(model, "leaves"):
        files += SavePlantFigure(result, out)
        files += SaveTargetPlanFigures(result, out)
        return files
    fig = plt.figure(figsize=(12, 5))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    est = st.initial_estimate
    if est is not None:
        leaf = est.semantic.leaf_points_W
        ax.scatter(*leaf.T, s=1, c="green", label="observed leaf")
        ax.scatter(*est.semantic.branch_points_W.T, s=1, c="saddlebrown", label="branch")
        if est.fruit is not None:
            ax.plot_trisurf(*est.fruit.vertices_W.T, triangles=est.fruit.faces, color="red",
                            alpha=0.3)
    if plan is not None and plan.chosen is not None:
        c = plan.chosen
        if c.deformed_leaf_W is not None:
            ax.scatter(*c.deformed_leaf_W.T, s=1, c="lime", label="predicted leaf")
        path = np.vstack([c.action.p_WG] + [p for p, _ in c.action.Poses(0.01)])
        ax.plot(*path[:-1].T, color="blue", linewidth=2)
        ax.quiver(*path[-2], *(path[-1] - path[-2]), color="blue", linewidth=2,
                  label=c.action.family)
        ax.set_title(f"chosen action: {c.action.Describe()}, "
                     f"E={c.energy:.2e}, N_vis={c.n_vis}")
    ax.legend(loc="upper left", fontsize=7)
    _EqualAxes(ax)
    ax2 = fig.add_subplot(1, 2, 2, projection="3d")
    if model is not None:
        gt = model.fruit_mesh_W
        ax2.plot_trisurf(*np.asarray(gt.vertices).T, triangles=np.asarray(gt.faces),
                         color="gray", alpha=0.25)
    for e, color, name in ((st.initial_estimate, "orange", "initial"),
                           (st.final_estimate, "blue", "final")):
        if e is not None and e.fruit is not None:
            v = e.fruit.vertices_W
            ax2.scatter(*v[::3].T, s=1, c=color, label=f"{name} estimate")
            ax2.quiver(*e.fruit.center_W, *(0.05 * e.fruit.peduncle_axis_W), color=color)
    if model is not None:
        ax2.quiver(*model.fruit_center_W, *(0.05 * model.peduncle_axis_W), color="black",
                   label="ground-truth axis")
    ax2.set_title("fruit estimates vs ground truth (gray)" if model is not None
                  else "fruit estimates (no ground truth on hardware)")
    ax2.legend(loc="upper left", fontsize=7)
    _EqualAxes(ax2)
    fig.tight_layout()
    fig.savefig(out / "action_and_shapes.png", dpi=110,
                pil_kwargs={"compress_level": PNG_COMPRESS_LEVEL})
    plt.close(fig)
    files.append("action_and_shapes.png")
    return files


def PlanOnImage(rgb, plan, estimate, K, X_WC: np.ndarray,
                observed_leaf: bool = True, max_dots: int = 3000) -> np.ndarray:
    """The camera image (greyed) with the planner's view of the chosen
    action drawn over it: the observed leaf (yellow), the predicted
    deformed leaf (green), the fruit estimate's outline (magenta), the grasp
    point and the pull (blue arrow), and a caption with the predicted
    energy and visibility. ``K``: ``perception.points.Intrinsics``; ``X_WC``
    4x4, the camera's pose in W. ``observed_leaf`` False leaves the observed
    leaf out; ``max_dots`` caps the dots per point set. Dense plants: the
    image is faded (greyed, lightened) so the drawing stands out from the
    canopy, and the target fruit and the grasp carry labels placed clear of
    the legend and of each other."""
    from PIL import ImageDraw
    base = RgbArray(rgb).astype(float)
    base = 0.3 * base + 0.7 * base.mean(axis=2, keepdims=True)
    base = 0.8 * base + 0.2 * 255.0
    img = Image.fromarray(np.clip(base, 0, 255).astype(np.uint8))
    draw = ImageDraw.Draw(img)
    w, h = img.size

    drawn = []                 # boxes of the point sets drawn: labels go beside them

    def dots(points, color, every=1, r=1):
        if points is None or len(points) == 0:
            return
        uv_all = ProjectPoints(np.asarray(points)[::every], K, X_WC)
        box = PointsBox(uv_all, (h, w))
        if box is not None:
            drawn.append(box)
        for u, v in uv_all:
            if np.isfinite(u) and 0 <= u < w and 0 <= v < h:
                draw.ellipse([u - r, v - r, u + r, v + r], fill=color)
    tags = []                  # (anchor u, v; text; colour)

    def centre(points):
        uv = ProjectPoints(np.asarray(points).reshape(-1, 3), K, X_WC)
        uv = uv[np.all(np.isfinite(uv), axis=1)]
        return tuple(uv.mean(axis=0)) if len(uv) else None
    if estimate is not None:
        if observed_leaf:
            dots(estimate.semantic.leaf_points_W, (255, 225, 0), max(1, len(
                estimate.semantic.leaf_points_W) // max_dots))
        if estimate.fruit is not None:
            dots(estimate.fruit.vertices_W, (255, 0, 200),
                 max(4, len(estimate.fruit.vertices_W) // max_dots))
            c_uv = centre(estimate.fruit.vertices_W)
            if c_uv is not None:
                tags.append((c_uv, "target fruit", (255, 0, 200)))
    lines = [f"plan: {plan.status} ({plan.method})"]
    c = plan.chosen
    if c is not None:
        if c.deformed_leaf_W is not None:
            dots(c.deformed_leaf_W, (60, 255, 60), max(1, len(c.deformed_leaf_W) // max_dots))
        a = c.action
        uv = ProjectPoints(np.vstack([a.p_WG] + [p for p, _ in a.Poses(0.005)]), K, X_WC)
        (u0, v0), (u1, v1) = uv[0], uv[-1]
        if np.all(np.isfinite(uv)):
            draw.line([tuple(x) for x in uv], fill=(0, 120, 255), width=3)
            draw.ellipse([u0 - 5, v0 - 5, u0 + 5, v0 + 5], outline=(0, 120, 255), width=2)
            tags.append(((u0, v0), f"grasp {a.grasp_id}", (0, 120, 255)))
            d = uv[-1] - uv[max(0, len(uv) - 4)]
            if np.linalg.norm(d) > 1:
                d /= np.linalg.norm(d)
                n = np.array([-d[1], d[0]])
                tip = np.array([u1, v1])
                draw.polygon([tuple(tip), tuple(tip - 9 * d + 5 * n), tuple(tip - 9 * d - 5 * n)],
                             fill=(0, 120, 255))
        e = c.EnergyPerNode()
        vis = (f"{plan.seen_init / plan.seen_max:.2f} -> {c.seen / plan.seen_max:.2f}"
               if plan.seen_max and c.seen >= 0 else "n/a")
        lines += [f"grasp {a.grasp_id}, {a.Describe()}",
                  f"predicted visibility {vis}",
                  "predicted energy/node " + (f"{e:.2e} m^2" if e is not None else "n/a")]
    else:
        lines.append(plan.message[:90])
    legend = [("observed leaf", (255, 225, 0)), ("predicted leaf", (60, 255, 60)),
              ("fruit estimate", (255, 0, 200)), ("grasp + motion", (0, 120, 255))]
    taken = _Legend(draw, [(t, (255, 255, 255)) for t in lines] + legend)
    corners = PlaceLabels([t[0] for t in tags], [TextBox(t[1]) for t in tags], (h, w),
                          taken + drawn)
    for (anchor, text, color), (u, v) in zip(tags, corners):
        bw, bh = TextBox(text)
        draw.line([(u + bw / 2, v + bh / 2), anchor], fill=color, width=1)
        draw.rectangle([u, v, u + bw, v + bh], fill=(0, 0, 0), outline=color)
        draw.text((u + 3, v + 1), text, fill=color)
    return np.asarray(img)


def SaveTargetPlanFigures(result, out: Path) -> list[str]:
    """Several fruits: ``plan_target<n>.png`` for the n-th target (the
    episode's ``targets[n]``) if it had an action,
    the prediction beside what happened: left, the plan over the view it was
    made in (``PlanOnImage``); right, the same predicted leaf and fruit
    estimate over the view taken while the leaf was held."""
    views = getattr(result, "views", ())
    st = result.status
    if not views:
        return []
    from PIL import ImageDraw

    from lmap_drake.perception.points import Intrinsics
    cam = result.world.scenario.cameras["camera0"]
    K = Intrinsics.FromCameraConfig(cam)
    X_WC = cam.X_PB.GetDeterministicValue().GetAsMatrix4()
    files = []
    for n, t in enumerate(st.targets):
        plan, k, k_after = t.get("plan"), t.get("view_plan"), t.get("view_after")
        if plan is None or plan.chosen is None or k is None or not 0 <= k < len(views):
            continue
        est = t.get("initial_estimate")
        panels = [PlanOnImage(views[k].rgb, plan, est, K, X_WC)]
        if k_after is not None and 0 <= k_after < len(views):
            held = Image.fromarray(PlanOnImage(views[k_after].rgb, plan, est, K, X_WC,
                                               observed_leaf=False, max_dots=400))
            draw = ImageDraw.Draw(held)
            draw.rectangle([0, 0, held.width, 66], fill=(0, 0, 0))
            draw.text((7, 5), f"what happened: view {k_after}, leaf held, with the "
                      f"predicted leaf (green) and fruit estimate (magenta)",
                      fill=(255, 255, 255))
            panels.append(np.asarray(held))
        name = f"plan_target{n}.png"
        SavePng(np.hstack(panels), out / name)
        files.append(name)
    return files


def PlantFigureLabels(targets: list[dict], same_fruit_m: float = 0.03,
                      min_gap_m: float = 0.045) -> list[dict]:
    """One label per fruit for the plant figure. ``targets``: one dict per
    handled target in episode order, ``center_W`` (3,) its fruit estimate's
    centre (W, m), ``leaf_id``, ``what`` (the action, or why there was none).
    Targets whose centres lie within ``same_fruit_m`` (the figure passes
    ``systems.planning.SAME_FRUIT_DISTANCE``) are one fruit (a fruit under
    two leaves is revealed twice; instance ids change between views).
    Returns per fruit, in order of first handling: ``center_W``, ``targets``
    (indices into ``targets``), ``text`` (every reveal: 'leaf 2: twist 60
    deg; then leaf 0: arc 30 deg') and ``anchor_W`` (W, m), where the label
    goes: 5 cm above the fruit, lifted further until it is ``min_gap_m``
    above or below every earlier label within 10 cm sideways, so labels of
    neighbouring fruits do not overlap."""
    fruits: list[dict] = []
    for i, t in enumerate(targets):
        c = np.asarray(t["center_W"], float).reshape(3)
        f = next((f for f in fruits if np.linalg.norm(f["center_W"] - c) < same_fruit_m), None)
        if f is None:
            f = {"center_W": c, "targets": []}
            fruits.append(f)
        f["targets"].append(i)
    placed: list[np.ndarray] = []
    for k, f in enumerate(fruits):
        f["text"] = f"fruit {k}: " + "; then ".join(
            (f"leaf {targets[i].get('leaf_id')}: " if targets[i].get("leaf_id") is not None
             else "no leaf: ") + targets[i]["what"] for i in f["targets"])
        a = f["center_W"] + [0.0, 0.0, 0.05]
        for _ in range(50):
            clash = [p for p in placed if np.linalg.norm((p - a)[:2]) < 0.10
                     and abs(p[2] - a[2]) < min_gap_m]
            if not clash:
                break
            a = a + [0.0, 0.0, min_gap_m / 2]
        placed.append(a)
        f["anchor_W"] = a
    return fruits


def SavePlantFigure(result, out: Path) -> list[str]:
    """Several fruits: the whole plant (observed leaves and branches of the
    first view) with every fruit's ground truth (grey, simulation only),
    each handled fruit's first estimate (orange) and its last re-estimate
    (blue), the fruits not planned for as first estimated (light blue), and
    one label per handled fruit naming each leaf moved and the action
    (``PlantFigureLabels``).

    Readable on dense plants: the leaves are faint except each target's
    chosen leaf (dark orange); in the plot each handled fruit carries only
    a short tag (``F0``, ``F1``, ...), its full text is listed under the
    plot; a legend names the colours."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    st = result.status
    model = getattr(result.world, "model", None)
    n_fruits = len({tuple(np.round((t.get("target") or {}).get("center_W") or [0, 0, 0], 2))
                    for t in st.targets})
    bottom = min(0.35, 0.05 + 0.025 * n_fruits)      # the list of fruits under the plot
    fig = plt.figure(figsize=(8, 7 / (1.0 - bottom)))
    ax = fig.add_axes([0.0, bottom, 1.0, 0.95 - bottom], projection="3d")
    first = st.targets[0]["initial_estimate"] if st.targets else st.initial_estimate
    if first is not None:
        sem = first.semantic
        ax.scatter(*np.asarray(sem.branch_points_W).reshape(-1, 3).T, s=1, c="saddlebrown")
        ax.scatter(*np.vstack([np.asarray(sem.leaf_points_W).reshape(-1, 3),
                               np.asarray(getattr(first, "other_leaves_W",
                                                  np.zeros((0, 3)))).reshape(-1, 3)]).T,
                   s=1, c="yellowgreen", alpha=0.25)
    for f in getattr(model, "fruits", []):
        ax.plot_trisurf(*np.asarray(f.mesh_W.vertices).T, triangles=np.asarray(f.mesh_W.faces),
                        color="gray", alpha=0.2)
    rows, first_of, last_of = [], [], []
    for t in st.targets:
        tg = t.get("target") or {}
        if tg.get("center_W") is None:
            continue
        plan = t.get("plan")
        what = (plan.chosen.action.Describe() if plan is not None and plan.chosen is not None
                else t["outcome"].split(":")[0])
        rows.append({"center_W": tg["center_W"], "leaf_id": tg.get("leaf_id"), "what": what})
        first_of.append(t.get("initial_estimate"))
        last_of.append(t.get("final_estimate") or t.get("initial_estimate"))
        est = t.get("initial_estimate")
        if est is not None and tg.get("leaf_id") is not None:
            chosen = np.asarray(est.semantic.leaf_points_W).reshape(-1, 3)
            ax.scatter(*chosen[::2].T, s=1.5, c="darkorange", alpha=0.6)
    from lmap_drake.systems.planning import SAME_FRUIT_DISTANCE
    labels = PlantFigureLabels(rows, SAME_FRUIT_DISTANCE)
    for k, lab in enumerate(labels):
        idx = lab["targets"]
        for e, color in ((first_of[idx[0]], "orange"), (last_of[idx[-1]], "blue")):
            if e is not None and e.fruit is not None:
                ax.scatter(*e.fruit.vertices_W[::4].T, s=1, c=color)
        ax.plot(*np.c_[lab["center_W"], lab["anchor_W"]], c="black", lw=0.5)
        ax.text(*lab["anchor_W"], f"F{k}", fontsize=8, fontweight="bold",
                bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="black", lw=0.5))
    for e in getattr(first, "other_fruits", []) if first is not None else []:
        c = getattr(e, "center_W", None)
        if c is None or any(np.linalg.norm(np.asarray(c) - lab["center_W"]) < SAME_FRUIT_DISTANCE
                            for lab in labels):
            continue
        ax.scatter(*e.vertices_W[::4].T, s=1, c="lightskyblue")
    ax.set_title("plant: fruits, estimates and the leaves chosen", fontsize=10)
    handles = [Line2D([], [], ls="", marker=m, color=c, label=n, markersize=7)
               for m, c, n in (("o", "gray", "fruit, ground truth"),
                               ("o", "orange", "first estimate"),
                               ("o", "blue", "last estimate"),
                               ("o", "lightskyblue", "fruit not planned for"),
                               (".", "darkorange", "leaf chosen for a target"),
                               (".", "yellowgreen", "other leaves (observed)"),
                               (".", "saddlebrown", "branches"))]
    ax.legend(handles=handles, loc="upper left", fontsize=7, framealpha=0.8)
    _EqualAxes(ax)
    text = "\n".join(f"F{k}: {lab['text'].split(': ', 1)[1]}" for k, lab in enumerate(labels))
    fig.text(0.03, bottom - 0.005, text or "no fruit handled", fontsize=8, va="top", family="monospace",
             wrap=True)
    fig.savefig(out / "plant_estimates.png", dpi=110,
                pil_kwargs={"compress_level": PNG_COMPRESS_LEVEL})
    plt.close(fig)
    return ["plant_estimates.png"]
