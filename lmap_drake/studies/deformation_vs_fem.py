"""The deformation-graph predictor (paper Sec. III-B) against the FEM leaf.

    python scripts/eval_deformation_vs_fem.py --out out/deformation_vs_fem.json
    python scripts/eval_deformation_vs_fem.py --out d.json \
        --scenarios small_leaf_thin_branch_round_red_heavy --corr_scenarios

Per scenario (default: every scenario in diagrams/suite.yaml):

1. ``PlantWorldSim`` settles 0.3 s; camera0 is segmented
   (``perception.segmenter``, the label segmenter by default) into a
   ``SemanticScene``; ``OracleSceneEstimate`` adds the exact branch (its
   surface samples are the "completed branch"); ``AttachLeaf`` adds the
   virtual petiole when the petiole is unseen.
2. The scripted tip grasp (``ApproachAndGrasp`` with ``plant_scene.pull``);
   the action is ``Action(p_WG, R_WG, dp_W)`` from the TCP pose ``X_WT``
   read after the grasp and ``dp_W = distance * direction`` (default: the
   scenario's ``pull.direction_W``, 4 cm).
3. Predicted: ``PredictDeformations(observed leaf + attachment, observed
   branch + completed branch samples, [action])``; its first rows are the
   observed leaf points deformed.
   Simulated: a fork of the grasped world is pulled (``Pull``, 1.5 s per
   4 cm, then 0.3 s hold). Each observed leaf point is tied to the FEM leaf
   by barycentric coordinates in its best tet of the settled (pre-approach)
   state (the tet where it lies most inside; points a little outside the
   thin leaf use the tet's affine map) and carried to the pulled state.
4. Error: mean distance (cm) between predicted and simulated positions of
   the observed points; baselines "no deformation" (the points stay) and
   "rigid translation" (every point moves by dp_W).

Correlation (``--corr_scenarios``, default one small-leaf and one
large-leaf scenario): from the same grasp, pulls along ``--corr_directions``
(scenario: ``pull.direction_W``; away: horizontal, from the leaf's branch
attachment to the grasp; lateral: horizontal, perpendicular to away, on the
side away from the fruit; up: +z) by ``--corr_distances``, each on its own
fork of the grasped world. All of one scenario's actions are predicted in one
``PredictDeformations`` call (one factorisation per grasp). Spearman rank
correlation between the predicted ARAP energy and the FEM measures of the
plant world (``PlantWorldSim.Sample``): the strain percentile and the
petiole force, at the end of the hold and the maximum over the pull, per
scenario and pooled.

Workarounds (recorded per scenario, never silent): a generated FEM leaf
with a near-degenerate tet is re-meshed with 5 % more target tets
(``leaf_mesh_note``; the large elliptic leaf of diagrams/suite.yaml gets a
zero-area sliver at the petiole end, which Drake rejects);
when the scripted approach has no IK solution the grasp moves 1.5 / 3 cm
farther from the tip (``grasp_note``, ``grasp_from_tip_m``).

Writes JSON ``{"mean_error_cm", "baselines", "scenarios": {name: {...}},
"correlation": {...}, "config": {...}}`` after every scenario (partial
results survive an interruption).
"""
from __future__ import annotations

import copy
import dataclasses as dc
import json
import sys
import time
import traceback
from pathlib import Path

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree
from scipy.stats import rankdata, spearmanr
from tqdm import tqdm

from lmap_drake.deformation import Action, PredictDeformations
from lmap_drake.paths import REPO_ROOT
from lmap_drake.perception.observe import SemanticSceneFromImages
from lmap_drake.planning.attachment import AttachLeaf
from lmap_drake.planning.motion import MotionError
from lmap_drake.plants.leaf import BoundaryTriangles, TetVolumes
from lmap_drake.plants.plant_sim import PlantWorldSim
from lmap_drake.plants.scripted import ApproachAndGrasp, OracleSceneEstimate, Pull
from lmap_drake.plants.plant_station import GetPlantModel
from lmap_drake.scenario import LoadScenario, ScenarioNames

DEFAULT_CORR = ["small_leaf_thin_branch_round_red_heavy",
                "large_leaf_thick_branch_round_red_heavy"]


@dc.dataclass
class DeformationVsFemOptions:
    """The study's settings (the flags of ``scripts/eval_deformation_vs_fem.py``)."""
    out: str = ""                    # JSON file written after every scenario
    scenario_file: Path = REPO_ROOT / "diagrams" / "suite.yaml"
    scenarios: list | None = None    # scenario names (None: every scenario in the file)
    corr_scenarios: list | None = None   # with correlation pulls (None: DEFAULT_CORR)
    corr_directions: list = dc.field(default_factory=lambda: ["scenario", "away", "lateral"])
    corr_distances: list = dc.field(default_factory=lambda: [0.02, 0.04, 0.06, 0.08])  # m
    distance: float = 0.04           # m: the main pull
    direction: list | None = None    # pull direction in W (None: the scenario's)
    speed: float = 0.04 / 1.5        # m/s: pull speed
    hold: float = 0.3                # s
    settle: float = 0.3              # s
    segmenter: str = "label"
    grasp_fallbacks: list = dc.field(default_factory=lambda: [0.0, 0.015, 0.03])  # m
    scenario_text: str = "{}"        # YAML overrides for every scenario
    keep_degenerate_leaf_mesh: bool = False


# --- the comparison (pure numpy; tested) ------------------------------------

def TetCorrespondence(V: np.ndarray, tets: np.ndarray, points: np.ndarray,
                      candidates: int = 12) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each point (N, 3), the tet of the mesh (V (M, 3), tets (T, 4)) it
    lies most inside among the ``candidates`` tets with the nearest centroids,
    and its barycentric coordinates there (N, 4; outside the tet some are
    negative: the tet's affine map extrapolates). Returns (tet index (N,),
    barycentrics (N, 4), min barycentric (N,): >= 0 means inside)."""
    V = np.asarray(V, float)
    tets = np.asarray(tets, int)
    P = np.asarray(points, float).reshape(-1, 3)
    k = int(min(candidates, len(tets)))
    _, cand = cKDTree(V[tets].mean(1)).query(P, k=k)
    cand = np.asarray(cand).reshape(len(P), k)
    best_t = np.zeros(len(P), int)
    best_b = np.zeros((len(P), 4))
    best_s = np.full(len(P), -np.inf)
    for j in range(k):
        t = tets[cand[:, j]]
        E = np.transpose(V[t[:, 1:]] - V[t[:, :1]], (0, 2, 1))   # columns: edges
        with np.errstate(all="ignore"):
            lam = np.linalg.solve(E, (P - V[t[:, 0]])[..., None])[..., 0]
        b = np.c_[1.0 - lam.sum(1), lam]
        s = np.where(np.isfinite(b).all(1), b.min(1), -np.inf)
        better = s > best_s
        best_s[better], best_t[better], best_b[better] = s[better], cand[better, j], b[better]
    return best_t, best_b, best_s


def CarryPoints(V_new: np.ndarray, tets: np.ndarray, tet_index: np.ndarray,
                bary: np.ndarray) -> np.ndarray:
    """Points (N, 3) with barycentrics ``bary`` in ``tets[tet_index]`` of the
    mesh whose vertices are now ``V_new``."""
    return np.einsum("ni,nij->nj", bary, np.asarray(V_new, float)[np.asarray(tets)[tet_index]])


def PointErrors(predicted: np.ndarray, simulated: np.ndarray, observed: np.ndarray,
                dp_W: np.ndarray) -> dict:
    """Distances (cm) between predicted and simulated points, with the
    no-deformation (``observed``) and rigid-translation (``observed + dp``)
    baselines."""
    def stats(a, key):
        e = np.linalg.norm(np.asarray(a) - simulated, axis=1) * 100.0
        return {f"{key}_cm": float(e.mean()), f"{key}_median_cm": float(np.median(e)),
                f"{key}_p90_cm": float(np.percentile(e, 90)), f"{key}_max_cm": float(e.max())}
    out = stats(predicted, "error")
    out["baseline_no_deformation_cm"] = stats(observed, "e")["e_cm"]
    out["baseline_rigid_translation_cm"] = stats(np.asarray(observed) + dp_W, "e")["e_cm"]
    out["simulated_mean_displacement_cm"] = float(
        np.linalg.norm(simulated - observed, axis=1).mean() * 100)
    out["predicted_mean_displacement_cm"] = float(
        np.linalg.norm(predicted - observed, axis=1).mean() * 100)
    return out


def Spearman(x, y) -> float | None:
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() < 3 or np.ptp(x[ok]) == 0 or np.ptp(y[ok]) == 0:
        return None
    return float(spearmanr(x[ok], y[ok]).statistic)


# --- the simulation side ----------------------------------------------------

def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _Directions(world, X_WT, names: list[str]) -> dict[str, np.ndarray]:
    p = X_WT.translation()
    away = p - world.model.leaf_attach_W
    away[2] = 0.0
    away = _unit(away)
    lateral = _unit(np.cross([0.0, 0.0, 1.0], away))
    if lateral @ (p - world.model.fruit_center_W) < 0:
        lateral = -lateral
    table = {"scenario": _unit(world.scenario.plant_scene.pull.direction_W),
             "away": away, "lateral": lateral, "up": np.array([0.0, 0.0, 1.0])}
    return {n: table[n] for n in names}


def LeafMeshWorkaround(scenario, max_tries: int = 6) -> tuple[object, str]:
    """``scenario`` unchanged if its generated FEM leaf has no near-degenerate
    tet; otherwise a copy with ``plant_scene.leaf.target_tets`` raised in 5 %
    steps until it has none (the leaf triangulation can put a zero-area
    sliver at the petiole end, which Drake rejects or fails on), and a note
    saying so ('' when unchanged)."""
    def worst(s):
        m = GetPlantModel(s)
        vol = TetVolumes(m.leaf_rest_W, m.leaf_tets)
        return float(np.abs(vol).min() / np.median(np.abs(vol)))
    r0 = worst(scenario)
    if r0 > 1e-3:
        return scenario, ""
    base = scenario.plant_scene.leaf.target_tets
    for k in range(1, max_tries + 1):
        s = copy.deepcopy(scenario)
        s.plant_scene.leaf.target_tets = int(round(base * (1 + 0.05 * k)))
        r = worst(s)
        if r > 1e-3:
            return s, (f"leaf mesh had a near-degenerate tet (min/median volume {r0:.1e}); "
                       f"plant_scene.leaf.target_tets {base} -> {s.plant_scene.leaf.target_tets}"
                       f" (min/median volume {r:.1e})")
    return scenario, f"leaf mesh has a near-degenerate tet (min/median volume {r0:.1e})"


def _PullAndMeasure(grasped, direction, distance, speed, hold, tets, corr) -> dict:
    """Forks ``grasped``, pulls, returns the FEM state and measures."""
    world = grasped.Fork()
    n0 = len(world.samples)
    p0 = world.X_WT().translation()
    t0 = time.perf_counter()
    Pull(world, direction, distance, max(0.5, distance / speed), hold)
    end = world.Sample()
    pull_samples = world.samples[n0:] + [end]
    tcp = world.X_WT().translation() - p0
    V = world.LeafVertices()
    return {
        "V": V, "sim_points": CarryPoints(V, tets, *corr[:2]),
        "row": {"sim_seconds": round(time.perf_counter() - t0, 2),
                "tcp_displacement_cm": float(np.linalg.norm(tcp) * 100),
                "tcp_error_cm": float(np.linalg.norm(tcp - distance * direction) * 100),
                "strain_percentile_end": end.strain_percentile,
                "strain_percentile_max": max(s.strain_percentile for s in pull_samples),
                "petiole_force_end_N": end.petiole_force,
                "petiole_force_max_N": max(s.petiole_force for s in pull_samples),
                "fruit_penetration_max_m": max(s.fruit_penetration for s in pull_samples),
                "fruit_contact_force_max_N": max(s.fruit_contact_force for s in pull_samples)}}


def _PredictionRow(p) -> dict:
    return {"energy": p.energy, "iterations": p.iterations, "converged": p.converged}


def EvaluateScenario(scenario, args: DeformationVsFemOptions, with_corr: bool, log) -> dict:
    timing = {}
    t0 = time.perf_counter()
    world = PlantWorldSim(scenario, progress=lambda m: log(f"    {m}"))
    world.Hold(args.settle)
    V_settled = world.LeafVertices()
    tets = world.model.leaf_tets
    im = world.Images()
    pcfg = dc.replace(scenario.perception, segmenter=args.segmenter)
    sem = SemanticSceneFromImages(im["rgb_image"], im["depth_image"], im["label_image"],
                                  scenario.cameras["camera0"], pcfg)
    obs = np.asarray(sem.leaf_points_W, float).reshape(-1, 3)
    obs = obs[np.isfinite(obs).all(1)]
    scene = OracleSceneEstimate(world, sem)
    scene, attach_msg = AttachLeaf(scene, scenario.deformation)
    leaf_in = np.vstack([obs, scene.leaf_attachment_W])
    branch_in = np.vstack([np.asarray(sem.branch_points_W, float).reshape(-1, 3),
                           scene.branch.samples_W])
    corr = TetCorrespondence(V_settled, tets, obs)
    # How well the observed points sit on the settled FEM leaf surface.
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(o3d.core.Tensor(V_settled.astype(np.float32)),
                     o3d.core.Tensor(BoundaryTriangles(tets).astype(np.uint32)))
    d_surf = rc.compute_distance(o3d.core.Tensor(obs.astype(np.float32))).numpy()
    timing["settle_observe_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    # The scripted tip grasp; if its approach has no IK solution (planning
    # fails before the arm moves), grasp farther from the tip (recorded).
    pull_cfg = scenario.plant_scene.pull
    grasp_note = ""
    for extra in args.grasp_fallbacks:
        cfg = dc.replace(pull_cfg, grasp_from_tip=pull_cfg.grasp_from_tip + extra)
        try:
            ApproachAndGrasp(world, cfg)
            break
        except MotionError as err:
            if extra == args.grasp_fallbacks[-1]:
                raise
            grasp_note += (f"grasp {cfg.grasp_from_tip * 100:.1f} cm from the tip: "
                           f"{str(err).split(':')[0]}; ")
            log(f"  approach IK failed at grasp_from_tip {cfg.grasp_from_tip:.3f}; "
                f"trying farther from the tip")
    X_WT = world.X_WT()
    disturbance = np.linalg.norm(CarryPoints(world.LeafVertices(), tets, *corr[:2]) - obs, axis=1)
    timing["approach_grasp_s"] = time.perf_counter() - t0
    p_WG, R_WG = X_WT.translation(), X_WT.rotation().matrix()

    dirs = _Directions(world, X_WT, ["scenario"] + (args.corr_directions if with_corr else []))
    main_dir = dirs["scenario"] if args.direction is None else _unit(args.direction)
    jobs = [("main", main_dir, args.distance)]
    if with_corr:
        jobs += [(f"{n}_{d * 100:g}cm", u, d) for n, u in dirs.items()
                 for d in args.corr_distances]
    actions = [Action(p_WG, R_WG, d * u) for _, u, d in jobs]
    t0 = time.perf_counter()
    preds = PredictDeformations(leaf_in, branch_in, actions, scenario.deformation)
    timing["predict_s"] = time.perf_counter() - t0
    timing["predict_actions"] = len(actions)
    n = len(obs)

    row = {"num_observed_leaf_points": n,
           "num_attachment_points": int(len(scene.leaf_attachment_W)),
           "num_branch_points": int(len(branch_in)),
           "attach_message": attach_msg,
           "observed_to_fem_surface_mean_mm": float(d_surf.mean() * 1000),
           "observed_to_fem_surface_p95_mm": float(np.percentile(d_surf, 95) * 1000),
           "fraction_points_inside_a_tet": float((corr[2] >= -1e-9).mean()),
           "approach_disturbance_mean_cm": float(disturbance.mean() * 100),
           "grasped_vertices": int(len(world.grasp_state.vertices)),
           "grasp_from_tip_m": cfg.grasp_from_tip, "grasp_note": grasp_note,
           "p_WG": p_WG.tolist(), "direction_W": main_dir.tolist(),
           "distance_m": args.distance}
    pulls = []
    sim_cache: dict[tuple, dict] = {}
    for (name, u, d), a, p in tqdm(list(zip(jobs, actions, preds)), desc="FEM pulls",
                                   unit="pull", file=sys.stderr):
        key = (tuple(np.round(u, 9)), round(d, 9))
        if key not in sim_cache:
            log(f"  pull {name}: {d * 100:g} cm along {np.round(u, 3).tolist()}")
            t1 = time.perf_counter()
            sim_cache[key] = _PullAndMeasure(world, u, d, args.speed, args.hold, tets, corr)
            timing["pull_s"] = timing.get("pull_s", 0.0) + time.perf_counter() - t1
        sim = sim_cache[key]
        r = {"name": name, "direction": name.split("_")[0] if name != "main" else "main",
             "distance_m": d, "direction_W": u.tolist()}
        r.update(_PredictionRow(p))
        r.update(sim["row"])
        r.update(PointErrors(p.leaf_points_W[:n], sim["sim_points"], obs, a.dp_W))
        if name == "main":
            row.update({k: v for k, v in r.items() if k not in ("name", "direction",
                                                                 "distance_m", "direction_W")})
        else:
            pulls.append(r)
    if pulls:
        row["pulls"] = pulls
    row["timing"] = {k: round(v, 2) for k, v in timing.items()}
    return row


CORR_MEASURES = ("strain_percentile_end", "strain_percentile_max",
                 "petiole_force_end_N", "petiole_force_max_N")


def Correlations(rows_by_scenario: dict[str, list[dict]]) -> dict:
    """Spearman(energy, measure) per scenario and pooled."""
    out = {"per_scenario": {}, "pooled": {}}
    pooled = [r for rows in rows_by_scenario.values() for r in rows]
    for name, rows in rows_by_scenario.items():
        out["per_scenario"][name] = {
            m: Spearman([r["energy"] for r in rows], [r[m] for r in rows]) for m in CORR_MEASURES}
        out["per_scenario"][name]["n"] = len(rows)
        # Reference: how well the pull distance alone ranks the same pulls.
        out["per_scenario"][name]["distance_instead_of_energy"] = {
            m: Spearman([r["distance_m"] for r in rows], [r[m] for r in rows])
            for m in CORR_MEASURES}
    out["pooled"] = {m: Spearman([r["energy"] for r in pooled], [r[m] for r in pooled])
                     for m in CORR_MEASURES}
    out["pooled"]["n"] = len(pooled)
    out["pooled"]["distance_instead_of_energy"] = {
        m: Spearman([r["distance_m"] for r in pooled], [r[m] for r in pooled])
        for m in CORR_MEASURES}
    out["pooled_rank_within_scenario"] = {}
    # Pooling raw energies mixes leaf sizes; also pool within-scenario ranks.
    if pooled:
        re, rm = [], {m: [] for m in CORR_MEASURES}
        for rows in rows_by_scenario.values():
            if len(rows) < 2:
                continue
            re += list(rankdata([r["energy"] for r in rows]) / len(rows))
            for m in CORR_MEASURES:
                rm[m] += list(rankdata([r[m] for r in rows]) / len(rows))
        out["pooled_rank_within_scenario"] = {m: Spearman(re, rm[m]) for m in CORR_MEASURES}
    return out


def _Summary(results: dict, args) -> dict:
    ok = {k: v for k, v in results.items() if "error_cm" in v}
    mean = lambda key: float(np.mean([v[key] for v in ok.values()])) if ok else None  # noqa
    corr_rows = {k: v["pulls"] for k, v in ok.items() if v.get("pulls")}
    return {
        "mean_error_cm": mean("error_cm"),
        "target_cm": 1.0,
        "num_scenarios": len(ok),
        "failed": {k: v["error"] for k, v in results.items() if "error_cm" not in v},
        # A grasp whose approach already moved the observed leaf (> 5 mm mean)
        # starts the FEM pull from a different leaf than the prediction.
        "mean_error_clean_grasp_cm": float(np.mean(
            [v["error_cm"] for v in ok.values() if v["approach_disturbance_mean_cm"] < 0.5]))
        if ok else None,
        "disturbed_grasps": [k for k, v in ok.items() if v["approach_disturbance_mean_cm"] >= 0.5],
        "baselines": {"no_deformation_cm": mean("baseline_no_deformation_cm"),
                      "rigid_translation_cm": mean("baseline_rigid_translation_cm")},
        "mean_error_p90_cm": mean("error_p90_cm"),
        "mean_approach_disturbance_cm": mean("approach_disturbance_mean_cm"),
        "correlation": Correlations(corr_rows) if corr_rows else None,
        "scenarios": results,
        "config": {"scenario_file": str(args.scenario_file), "segmenter": args.segmenter,
                   "distance_m": args.distance, "direction": args.direction or "scenario",
                   "pull_speed_m_per_s": args.speed, "hold_s": args.hold,
                   "settle_s": args.settle, "corr_directions": args.corr_directions,
                   "corr_distances_m": args.corr_distances,
                   "scenario_text": args.scenario_text,
                   "scene_estimate": "OracleSceneEstimate (exact branch; fruit unused)"},
    }


def RunDeformationVsFem(args: DeformationVsFemOptions) -> int:
    """The study on every scenario of ``args`` (see the module docstring);
    writes ``args.out`` after each. Returns 0 when every scenario was
    evaluated, else 1."""
    names = args.scenarios or ScenarioNames(args.scenario_file)
    corr = DEFAULT_CORR if args.corr_scenarios is None else args.corr_scenarios
    t_start = time.perf_counter()

    def log(msg):
        print(f"[{time.perf_counter() - t_start:7.1f} s] {msg}", flush=True)

    results: dict[str, dict] = {}
    for i, name in enumerate(names):
        log(f"({i + 1}/{len(names)}) {name}{' (+ correlation pulls)' if name in corr else ''}")
        try:
            s = LoadScenario(filename=args.scenario_file, scenario_name=name,
                             scenario_text=args.scenario_text)
            note = ""
            if not args.keep_degenerate_leaf_mesh:
                s, note = LeafMeshWorkaround(s)
                if note:
                    log(f"  {note}")
            results[name] = EvaluateScenario(s, args, name in corr, log)
            r = results[name]
            r["leaf_mesh_note"] = note
            r["leaf_target_tets"] = s.plant_scene.leaf.target_tets
            log(f"  error {r['error_cm']:.3f} cm (median {r['error_median_cm']:.3f}, "
                f"p90 {r['error_p90_cm']:.3f}); no deformation "
                f"{r['baseline_no_deformation_cm']:.3f}, rigid "
                f"{r['baseline_rigid_translation_cm']:.3f}; energy {r['energy']:.3g}")
        except Exception as err:  # keep going: one bad scenario must not lose the rest
            traceback.print_exc()
            results[name] = {"error": f"{type(err).__name__}: {err}"}
        summary = _Summary(results, args)
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(summary, indent=1))
    summary["seconds"] = round(time.perf_counter() - t_start, 1)
    Path(args.out).write_text(json.dumps(summary, indent=1))
    brief = {k: summary[k] for k in ("mean_error_cm", "baselines", "num_scenarios", "failed")}
    brief["scenarios"] = {k: v.get("error_cm", v.get("error")) for k, v in results.items()}
    brief["correlation"] = summary["correlation"] and {
        k: summary["correlation"][k] for k in ("pooled", "pooled_rank_within_scenario")}
    print(json.dumps(brief, indent=1))
    return 0 if summary["num_scenarios"] == len(names) else 1
