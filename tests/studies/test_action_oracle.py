"""lmap_drake.studies.action_oracle: the ranking of candidates to execute and the
per-scene summary of measured outcomes (the episodes themselves run in
``scripts/action_oracle.py``, not here)."""
from lmap_drake.studies.action_oracle import Ranked, Summary


def _cand(g, d, dist, seen, epn=1e-7, predicted=True, reason=""):
    return {"grasp_id": g, "direction_id": d, "distance": dist, "seen": seen,
            "energy_per_node": epn, "predicted": predicted, "reason": reason}


def test_ranked_takes_predicted_candidates_by_visibility_without_the_choice():
    cands = [_cand(0, 2, 0.04, 50), _cand(1, 2, 0.06, 90, reason="above max_energy_per_node"),
             _cand(2, 0, 0.02, 90, epn=5e-8), _cand(3, 1, 0.08, 99, predicted=False,
                                                    reason="IK failed"),
             _cand(4, 2, 0.04, -1), _cand(5, 2, 0.04, 70)]
    top = Ranked(cands, 100, (5, 2, 0.04), 3)
    assert [(c["grasp_id"], c["distance"]) for c in top] == [(2, 0.02), (1, 0.06), (0, 0.04)]
    assert top[0]["predicted_visibility"] == 0.9


def _row(vis, safe, choice=False, initial=0.2):
    return {"action": [0, 0, 0.04], "lmap_choice": choice,
            "outcome": {"visibility_final": vis, "visibility_initial": initial, "safe": safe,
                        "max_petiole_force": 10.0}}


def test_summary_counts_only_safe_actions():
    s = Summary([_row(0.8, True, choice=True), _row(0.99, False), _row(0.96, True),
                      _row(0.9, True)])
    assert s["lmap_visibility"] == 0.8 and s["lmap_safe"]
    assert s["best_safe_visibility"] == 0.96 and s["safe"] == 3 and s["executed"] == 4
    assert s["safe_reaching_threshold"] == 1
    none = Summary([_row(0.99, False, choice=True)])
    assert none["best_safe_visibility"] is None and none["visibility_initial"] == 0.2
