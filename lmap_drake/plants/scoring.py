"""Ground-truth scoring of an episode on the simulated plant world: the
outcome flags, visibilities and shape errors that ``episode.sim_world.SimWorld``
writes into ``episode.json`` (``outcome``, ``release_outcome``,
``shape_initial`` / ``shape_final``, ``leaf_loads`` (per FEM leaf: its
worst petiole force, strain and robot contact force, grasped or brushed),
and for several fruits ``fruits``, ``targets``, ``phantom_targets``).
Never from the planner's model: from the plant world's samples
(``PlantWorldSim.samples``), its render labels and the generated plant
(``PlantWorldSim.model``). World frame W, metres, newtons.
"""
from __future__ import annotations

import numpy as np

from lmap_drake.labels import LEAF
from lmap_drake.perception.points import Intrinsics
from lmap_drake.plants.outcome import (FruitShapeErrors, LeafLoadRows, ShapeErrors, Summarize,
                                       TruthFruitOfInstance, TruthInstanceOfPoints)
from lmap_drake.plants.plant_sim import PlantWorldSim
from lmap_drake.scenario import Scenario
from lmap_drake.shape.completion import DroppedFragments


def ScoreEpisode(record: dict, sim: PlantWorldSim, scenario: Scenario, views, st,
                 vis_initial: float | None, release_sample: int | None) -> float | None:
    """Ground truth into the episode ``record``: outcome flags (up to the
    release, ``sim.samples[:release_sample]``; the release and retreat
    separately), visibility in the two captured views (what the planner saw,
    and after the action), shape errors. ``views``: the episode's captured
    views (``.label`` the render labels); ``st``: the ArmController's status;
    ``vis_initial``: the visibility when the episode started. Returns the
    initial visibility scored (that of the first view when it has labels)."""
    record["robot_contact"] = dict(sim.worst_robot_contact)   # what touched, if anything
    # every FEM leaf's worst loads over the whole episode (grasped, brushed)
    record["leaf_loads"] = LeafLoadRows(sim.samples, scenario.plant_scene.outcome)
    if getattr(sim, "multi", False):
        ScorePlantEpisode(record, sim, scenario, views, st)
        return vis_initial
    if views and views[0].label is not None:     # what the planner saw
        vis_initial = sim.Visibility(views[0].label)
    if len(views) >= 2 and views[-1].label is not None:   # after the last motion
        vis_final = sim.Visibility(views[-1].label)
    else:
        vis_final = sim.Visibility()
    cut = release_sample if release_sample is not None else len(sim.samples)
    cfg = scenario.plant_scene.outcome
    record["outcome"] = Summarize(sim.samples[:cut], cfg, vis_initial,
                                  vis_final).to_dict()
    if release_sample is not None:
        after = Summarize(sim.samples[cut:], cfg, vis_final, sim.Visibility()).to_dict()
        record["release_outcome"] = {k: after[k] for k in (
            "plant_hazard", "fruit_collision", "max_petiole_force",
            "max_fruit_penetration", "max_fruit_contact_force")}
        record["release_outcome"]["visibility_after_release"] = after["visibility_final"]
    model = sim.model
    record["shape_initial"] = ShapeErrors(st.initial_estimate, model)
    record["shape_final"] = ShapeErrors(st.final_estimate, model)
    record["plant"] = {"occlusion_requested": model.occlusion_requested,
                       "occlusion_predicted": model.occlusion_predicted,
                       "occlusion_clamped": model.occlusion_clamped}
    record["simulated_seconds"] = sim.time
    return vis_initial


def ScorePlantEpisode(record: dict, sim: PlantWorldSim, scenario: Scenario, views,
                      st) -> None:
    """Several fruits (``kind: multi``): the plant-level outcome over the whole episode
    (every grasp, motion, release and retreat) and one ``fruits`` entry
    per ground-truth fruit: its visibility in the first view and after
    its reveal (in the view observed after its last motion; unchanged
    when it was not moved for), the shape metrics of its estimate before
    and after, and the target record (leaf chosen, why, motions). A
    target is matched to the true fruit its points land on in the render
    labels of its view; a target whose points are mostly not on a fruit
    is a phantom (``targets[k].phantom``, ``phantom_targets``; e.g. a
    stalk segmented as fruit) and is no fruit's estimate."""
    model = sim.model
    label = [v.label for v in views]

    def vis(i, k):
        return sim.Visibility(label[k], fruit=i) if 0 <= k < len(label) and \
            label[k] is not None else sim.Visibility(fruit=i)
    def during(t):
        return [s for s in sim.samples
                if t["t_start"] - 1e-9 <= s.t <= t["t_end"] + 1e-9]

    def worst_load(t):
        """The sample of largest petiole force (any leaf) while target
        ``t`` was handled, or None."""
        d = during(t)
        return max(d, key=lambda s: s.petiole_force) if d else None

    def worst_strain(t):
        """The largest blade strain percentile (any leaf) while target
        ``t`` was handled, or None."""
        d = during(t)
        return float(max(s.strain_percentile for s in d)) if d else None
    K = Intrinsics.FromCameraConfig(scenario.cameras["camera0"])

    def truth_of(t):
        """(true fruit, fraction of the target's points on a fruit): from
        the render labels of the view it was planned in; a phantom
        (points mostly not on a fruit) is (None, fraction); without
        those, the fruit nearest the target's estimated centre."""
        est, k = t.get("initial_estimate"), t.get("view_plan")
        if est is not None and k is not None and 0 <= k < len(label) \
                and label[k] is not None:
            found = TruthFruitOfInstance(est.semantic, t["target"].get("fruit_id"),
                                         label[k], K)
            if found is not None:
                return found
        c = np.asarray(t["target"]["center_W"], float)
        return int(np.argmin([np.linalg.norm(f.center_W - c) for f in model.fruits])), None

    def true_leaf(t):
        """The true leaf (ground-truth index) target ``t`` moved: where
        its leaf instance's points land in the labels of the view it was
        planned in; None without a leaf, labels or a majority on a leaf."""
        est, k = t.get("initial_estimate"), t.get("view_plan")
        if t["target"].get("leaf_id") is None or est is None or k is None \
                or not 0 <= k < len(label) or label[k] is None:
            return None
        return TruthInstanceOfPoints(est.semantic.leaf_points_W, label[k], K,
                                     est.semantic.X_WC, LEAF)[0]

    def dropped(est):
        sem = getattr(est, "semantic", None)
        return None if sem is None else DroppedFragments(sem.flags)

    def executed(u):
        """The candidates target ``u`` executed (its plan, then its
        continuations), in order."""
        plans = ([u["plan"]] if u["plan"] is not None else []) + u["continuations"]
        return [p.chosen for p in plans if p.chosen is not None][:u["motions"]]
    targets = {}
    rows = []           # every target in turn, also a second one on the same fruit
    for t in st.targets:
        if t.get("target"):
            i, on_fruit = truth_of(t)
            if i is not None:
                targets.setdefault(i, []).append(t)
            worst = worst_load(t)
            leaf = true_leaf(t)
            occluders = [] if i is None else list(model.fruits[i].occluders)
            rows.append({"fruit": i, "phantom": i is None,
                         # the true leaf moved and whether it hides that fruit
                         "leaf_true": leaf, "true_occluders": occluders,
                         "leaf_is_occluder": None if leaf is None else leaf in occluders,
                         "points_on_fruit": None if on_fruit is None else round(on_fruit, 3),
                         "fruit_id": t["target"].get("fruit_id"),
                         "center_W": t["target"]["center_W"],
                         "leaf_id": t["target"].get("leaf_id"), "outcome": t["outcome"],
                         "motions": [c.action.Describe() for c in executed(t)],
                         "t_start": t["t_start"], "t_end": t["t_end"],
                         "force_stop": t.get("force_stop") or None,
                         "force_peak_N": t.get("force_peak_N"),
                         "max_petiole_force": (None if worst is None
                                               else float(worst.petiole_force)),
                         "max_strain_percentile": worst_strain(t),
                         # the FEM leaves the robot touched meanwhile, with their loads
                         "leaf_loads": [r for r in LeafLoadRows(
                             during(t), scenario.plant_scene.outcome) if r["touched"]],
                         # fruit fragments dropped as no fruit (CompletePlant)
                         # in the view it was planned in and in its re-estimate
                         "fragments_dropped": [dropped(t.get(k)) for k in
                                               ("initial_estimate", "final_estimate")]})
    record["targets"] = rows
    record["phantom_targets"] = sum(r["phantom"] for r in rows)
    fruits = []
    for i, f in enumerate(model.fruits):
        ts = targets.get(i, [])
        t = ts[0] if ts else None
        v0 = vis(i, 0)
        entry = {"fruit": i, "occlusion_requested": f.occlusion_requested,
                 "occluders": list(f.occluders),
                 "one_leaf_ceiling": float(getattr(f, "one_leaf_ceiling", 1.0)),
                 "visibility_initial": v0, "visibility_final": v0,
                 "targeted": t is not None, "shape_initial": None, "shape_final": None,
                 "action": None, "motions": [], "leaf_id": None, "why": "",
                 "outcome": "not planned for (predicted visible, or not seen)",
                 "reveals": []}
        if t is not None:
            # a fruit under two leaves may be revealed twice, each time
            # by another leaf: its final visibility is the best view a
            # reveal gave, its final shape the last re-estimate's
            ini = t["initial_estimate"].fruit if t["initial_estimate"] else None
            last = next((u for u in ts[::-1] if u["final_estimate"] is not None
                         and u["motions"]), t)
            fin = last["final_estimate"].fruit if last["final_estimate"] else None
            after = [vis(i, u["view_after"]) for u in ts if u["view_after"] is not None]
            entry.update(
                visibility_initial=vis(i, t["view_plan"]),
                visibility_final=max(after) if after else vis(i, t["view_plan"]),
                shape_initial=FruitShapeErrors(ini, f.mesh_W, f.peduncle_axis_W),
                shape_final=FruitShapeErrors(fin or ini, f.mesh_W, f.peduncle_axis_W),
                action=(t["plan"].chosen.Row() if t["plan"] is not None
                        and t["plan"].chosen is not None else None),
                motions=[c.Row() for u in ts for c in executed(u)],
                leaf_id=t["target"].get("leaf_id"), why=t["target"].get("why", ""),
                outcome=t["outcome"],
                reveals=[{"leaf_id": u["target"].get("leaf_id"),
                          "why": u["target"].get("why", ""), "outcome": u["outcome"],
                          "motions": u["motions"],
                          "visibility_after": (None if u["view_after"] is None
                                               else vis(i, u["view_after"]))}
                         for u in ts])
            # the petiole load while this fruit was handled (any leaf), N
            loads = [(worst_load(u), u) for u in ts]
            loads = [(w, u) for w, u in loads if w is not None]
            if loads:
                worst, _ = max(loads, key=lambda wu: wu[0].petiole_force)
                entry.update(max_petiole_force=float(worst.petiole_force),
                             max_petiole_force_t=float(worst.t),
                             max_strain_percentile=max(worst_strain(u) for _, u in loads))
        # every captured view together: what the fused views saw of it
        # (a fruit under two leaves shows different parts as each is moved)
        shown = [x for x in label if x is not None]
        entry["visibility_union"] = sim.VisibilityUnion(shown, fruit=i) if shown else v0
        fruits.append(entry)
    record["fruits"] = fruits
    cfg = scenario.plant_scene.outcome
    v0 = [e["visibility_initial"] for e in fruits]
    v1 = [e["visibility_final"] for e in fruits]
    record["outcome"] = Summarize(sim.samples, cfg, float(np.mean(v0)),
                                  float(np.mean(v1))).to_dict()
    record["outcome"]["fruits_revealed"] = int(sum(v >= 0.9 for v in v1))
    # the fruits one leaf's move could show >= 0.9 (the rest need two leaves moved)
    record["outcome"]["fruits_one_leaf_reachable"] = int(
        sum(e["one_leaf_ceiling"] >= 0.9 for e in fruits))
    shapes = [(e["shape_initial"], e["shape_final"]) for e in fruits if e["shape_final"]]
    mean = (lambda rows: None if not rows else
            {k: float(np.mean([r[k] for r in rows])) for k in rows[0]})
    record["shape_initial"] = mean([a for a, _ in shapes if a])
    record["shape_final"] = mean([b for _, b in shapes])
    record["plant"] = {"fruits": len(model.fruits), "leaves": len(model.leaves)}
    record["simulated_seconds"] = sim.time
