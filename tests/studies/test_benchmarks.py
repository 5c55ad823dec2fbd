"""The benchmarks' pure parts (``studies.engines_benchmark``,
``deformation_benchmark``, ``multi_suite``, ``plant_plans``), without
running an episode; the scripts around them are checked for their flags in
``test_script_shells.py``."""
from types import SimpleNamespace

import numpy as np

from lmap_drake.deformation.synthetic import OvateLeaf
from lmap_drake.labels import FRUIT, LEAF, EncodeLabel
from lmap_drake.studies.deformation_benchmark import BoundaryGrasps
from lmap_drake.studies.engines_benchmark import PLAN_CORES, Costs, Differences, Plan
from lmap_drake.studies.multi_suite import LabelColors
from lmap_drake.studies.plant_plans import RejectionReasons


def _record(eid, method="lmap", cpu=2.0, wall=3.0, **fields):
    return {"eval": {"episode_id": eid, "method": method}, "cpu_seconds": cpu,
            "wall_seconds": wall, **fields}


def test_engine_differences_ignore_timings_and_name_fields_and_missing_episodes():
    a = {"e1": _record("e1", outcome=1), "e2": _record("e2")}
    b = {"e1": _record("e1", cpu=9.0, wall=9.0, outcome=1), "e3": _record("e3")}
    assert Differences(a, a) == []
    assert Differences(a, b) == ["e2: missing", "e3: missing"]
    b["e1"]["outcome"] = 2
    assert Differences(a, b) == ["e2: missing", "e3: missing", "e1: outcome"]


def test_engine_costs_and_the_1000_episode_plan():
    records = [_record("a", cpu=1.0, wall=2.0), _record("b", cpu=3.0, wall=4.0),
               _record("c", cpu=5.0, wall=6.0), _record("d", method="upward", cpu=2.0),
               _record("e", cpu=100.0, status="error")]
    costs = Costs(records)
    assert costs["lmap"]["cpu_seconds"] == {"median": 3.0, "min": 1.0, "max": 5.0, "n": 3}
    assert costs["lmap"]["wall_seconds"]["median"] == 4.0
    plan = Plan(costs)
    assert plan["lmap"]["core_hours"] == 1000 * 3.0 / 3600.0
    assert plan["upward"]["seconds_per_episode"] == 2.0
    assert set(plan["lmap"]["wall_hours_on_cores"]) == {str(n) for n in PLAN_CORES}


def test_boundary_grasps_are_spread_on_the_leaf_with_rotations():
    leaf, _ = OvateLeaf(spacing=0.004, p_WL=[0.5, -0.1, 0.35])
    grasps = BoundaryGrasps(leaf, 15, 0.01)
    assert len(grasps) == 15
    for p_WG, R_WG in grasps:
        assert np.min(np.linalg.norm(leaf - p_WG, axis=1)) == 0.0   # a leaf point
        assert np.allclose(R_WG.T @ R_WG, np.eye(3), atol=1e-9)
    assert len({tuple(p) for p, _ in grasps}) > 10


def test_label_colors_give_background_and_a_colour_per_class():
    label = np.array([[0, EncodeLabel(LEAF, 1)], [EncodeLabel(FRUIT, 0), EncodeLabel(FRUIT, 2)]])
    rgb = LabelColors(label)
    assert rgb.shape == (2, 2, 3) and rgb.dtype == np.uint8
    assert (rgb[0, 0] == 235).all()
    assert rgb[0, 1, 1] > rgb[0, 1, 0] and rgb[1, 0, 0] > rgb[1, 0, 1]
    assert not (rgb[1, 0] == rgb[1, 1]).all()                      # instances differ


def test_rejection_reasons_count_with_numbers_masked():
    plan = SimpleNamespace(candidates=[SimpleNamespace(reason=r) for r in
                                       ("", "IK failed (3 tries)", "energy 1.5e-3 > cap",
                                        "energy 2.0 > cap", "")])
    assert RejectionReasons(plan) == {"feasible": 2, "IK failed": 1, "energy # > cap": 2}


def test_the_planner_benchmark_record_changes_with_any_verdict_or_choice():
    import json
    from lmap_drake.deformation.action import Action
    from lmap_drake.planning.result import Candidate, PlanResult
    from lmap_drake.studies.planner_benchmark import _PlanRecord

    def plan(reason="", chosen=True):
        cands = [Candidate(Action(np.zeros(3), np.eye(3), np.array([0, 0, 0.04]), 0, 0), 1),
                 Candidate(Action(np.zeros(3), np.eye(3), np.array([0, 0.04, 0]), 1, 2), 1,
                           reason=reason)]
        return PlanResult("ok", "lmap", chosen=cands[1] if chosen else cands[0],
                          candidates=cands, target={"fruit_id": 3, "leaf_id": 7})

    def same(a, b):
        return json.dumps(_PlanRecord(a), sort_keys=True) == json.dumps(_PlanRecord(b),
                                                                        sort_keys=True)
    assert same(plan(), plan())
    assert not same(plan(), plan(chosen=False))                  # another action chosen
    assert not same(plan(), plan(reason="robot-fruit (3.0 mm)"))  # another verdict
    assert _PlanRecord(plan())["leaf_id"] == 7
    # the same plan from another process: energies differ in the last digits
    from lmap_drake.studies.planner_benchmark import SamePlan
    a, b = plan(), plan()
    a.chosen.energy, b.chosen.energy = 5.597331689463103e-05, 5.597331689907192e-05
    assert SamePlan(_PlanRecord(a), _PlanRecord(b))
    b.chosen.energy = 5.6e-05
    assert not SamePlan(_PlanRecord(a), _PlanRecord(b))
