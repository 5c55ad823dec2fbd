"""Pictures of the shape-completion evaluation: one case's observed points,
the true fruit and each method's estimate, seen from the camera and from the
side (matplotlib PNGs). The episode's pictures are in ``episode.figures``."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from lmap_drake.viz import PNG_COMPRESS_LEVEL


# Outline colours of the shape-completion methods (``ShapeCaseFigure``).
METHOD_COLORS = {"supeps": "tab:purple", "homa": "tab:blue", "ssc": "tab:red"}
NAME_OF_METHOD = {"supeps": "SupEps", "homa": "HoMa-style", "ssc": "SSC"}


def ShapeViewAxes(X_WC: np.ndarray, center_W: np.ndarray) -> tuple[np.ndarray, ...]:
    """Unit vectors (W) of the two views of ``ShapeCaseFigure``: ``ray``
    from the camera to ``center_W``, ``up`` (world +z made orthogonal to
    the ray) and ``right`` (= ray x up, to the right in the camera's view)."""
    ray = np.asarray(center_W, float) - np.asarray(X_WC, float)[:3, 3]
    ray /= np.linalg.norm(ray)
    up = np.array([0.0, 0.0, 1.0]) - ray[2] * ray
    up /= np.linalg.norm(up)
    return ray, up, np.cross(ray, up)


def _Outline(ax, xy: np.ndarray, **kw):
    """The convex outline of 2D points (a pepper's silhouette is nearly convex)."""
    from scipy.spatial import ConvexHull
    if len(xy) < 3:
        return
    h = ConvexHull(xy)
    loop = np.r_[h.vertices, h.vertices[:1]]
    return ax.plot(xy[loop, 0], xy[loop, 1], **kw)


def ShapeCaseFigure(semantic, gt_vertices_W: np.ndarray, gt_center_W: np.ndarray,
                    estimates: dict, metrics: dict, path: Path, title: str = "") -> None:
    """One shape-completion case as a PNG: the camera's view and a side view
    (cm about the true centre; the side view has the camera on the left),
    with the observed leaf, branch and fruit points, the true fruit (grey)
    and each method's estimate outlined, its shape hypotheses dotted
    (``estimates``: method ->
    FruitEstimate; ``metrics``: method -> ShapeMetrics dict for the legend)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    c = np.asarray(gt_center_W, float)
    ray, up, right = ShapeViewAxes(semantic.X_WC, c)
    views = (("camera view", right, "right (cm)"), ("side view, camera on the left", ray,
                                                    "depth along the view ray (cm)"))
    fig, axes = plt.subplots(1, 2, figsize=(11, 6.6))
    for ax, (name, h_axis, h_label) in zip(axes, views):
        def xy(p):
            q = (np.asarray(p, float).reshape(-1, 3) - c) * 100.0
            return np.c_[q @ h_axis, q @ up]
        near = lambda p: p[np.linalg.norm(np.asarray(p, float).reshape(-1, 3) - c, axis=1) < 0.12]
        gt = xy(gt_vertices_W)
        ax.scatter(*gt.T, s=2, c="0.75", label="true fruit", zorder=1)
        lf, br = xy(near(semantic.leaf_points_W)), xy(near(semantic.branch_points_W))
        ax.scatter(*lf.T, s=1, c="tab:green", alpha=0.25, label="observed leaf", zorder=2)
        ax.scatter(*br.T, s=1, c="saddlebrown", alpha=0.4, label="observed branch", zorder=2)
        ax.scatter(*xy(semantic.fruit_points_W).T, s=3, c="orange", label="observed fruit",
                   zorder=4)
        for m, est in estimates.items():
            if est is None or not len(est.vertices_W):
                continue
            r = metrics.get(m, {})
            label = NAME_OF_METHOD.get(m, m) + (
                f": {r['chamfer_cm']:.2f} cm / {r['volume_err_cm3']:.0f} cm³ / "
                f"{r['center_err_cm']:.2f} cm / {r['angle_err_deg']:.1f}°" if r else "")
            _Outline(ax, xy(est.vertices_W), color=METHOD_COLORS.get(m, "k"), lw=1.8,
                     label=label, zorder=5)
            hyp = getattr(est, "hypotheses", None)
            for k, v in enumerate(hyp.vertices_W if hyp is not None else []):
                lo, hi = hyp.volume_interval_cm3
                _Outline(ax, xy(v), color=METHOD_COLORS.get(m, "k"), lw=0.6, ls=":",
                         zorder=3, label=(f"{NAME_OF_METHOD.get(m, m)} hypotheses "
                                          f"({len(hyp.vertices_W)} kept, {lo:.0f}-{hi:.0f} "
                                          f"cm³)") if k == 0 else None)
        ax.plot(0, 0, "k+", ms=10, zorder=6)
        lim = max(6.0, float(np.abs(gt).max()) * 1.6)
        ax.set_xlim(-lim, lim)
        ax.set_ylim(-lim, lim)
        ax.set_aspect("equal")
        ax.set_xlabel(h_label)
        ax.set_ylabel("up (cm)")
        ax.set_title(name, fontsize=10)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, 0.17, 1, 1))
    fig.legend(handles, labels, loc="lower center", ncol=2, fontsize=8, markerscale=3,
               frameon=False, title="estimates: Chamfer / volume / centre / axis error",
               title_fontsize=8)
    fig.savefig(path, dpi=90, pil_kwargs={"compress_level": PNG_COMPRESS_LEVEL})
    plt.close(fig)
