"""The hinge-misfit check: a turn about a wrong hinge estimate moves the true
attachment in the gripper's frame, and the held blade must take it up."""
import dataclasses as dc

import numpy as np
import pytest

from lmap_drake.deformation.action import Action, MakeArcActions, MakeTwistActions
from lmap_drake.planning.config import PlannerConfig
from lmap_drake.planning.hazard import (AttachmentMisfit, HingeMisfitStrain, MisfitReason,
                                        TurnAngle)
from lmap_drake.planning.result import Candidate
from lmap_drake.planning.selection import RejectionCounts, _ScoreAndVeto

R0 = np.eye(3)
HINGE = np.array([0.0, 0.0, 0.0])


def _twist(lever: float, deg: float) -> Action:
    return MakeTwistActions(np.array([lever, 0.0, 0.0]), R0, HINGE, [np.radians(deg)])[0]


def test_a_turn_about_the_true_attachment_has_no_misfit_a_wrong_one_has_its_bound():
    a = _twist(0.05, 60.0)
    assert AttachmentMisfit(a, HINGE) == pytest.approx(0.0, abs=1e-12)
    # the true attachment 2 cm off the twist axis: |(R - I) e| = 2 sin(30 deg) 2 cm
    assert AttachmentMisfit(a, HINGE + [0.0, 0.02, 0.0]) == pytest.approx(0.02, rel=1e-9)
    # on the axis the twist does not move it
    assert AttachmentMisfit(a, HINGE + [0.01, 0.0, 0.0]) == pytest.approx(0.0, abs=1e-12)
    arc = MakeArcActions(np.array([0.05, 0.0, 0.0]), R0, HINGE, np.array([[0.0, 0.0, 1.0]]),
                         [np.radians(30.0)])[0]
    e = np.array([0.0, 0.0, 0.015])        # along the arc's axis: not moved
    assert AttachmentMisfit(arc, HINGE + e) == pytest.approx(0.0, abs=1e-12)
    e = np.array([0.0, 0.015, 0.0])
    bound = HingeMisfitStrain(np.radians(30.0), 1.0, 0.015)
    assert AttachmentMisfit(arc, HINGE + e) == pytest.approx(bound, rel=1e-9)
    pull = Action(np.array([0.05, 0.0, 0.0]), R0, np.array([0.0, 0.03, 0.0]))
    assert AttachmentMisfit(pull, HINGE + e) == pytest.approx(0.03)


def test_misfit_strain_grows_with_the_turn_and_the_shorter_lever():
    s = HingeMisfitStrain(np.radians(60.0), 0.04, 0.02)
    assert s == pytest.approx(0.5)
    assert HingeMisfitStrain(np.radians(30.0), 0.04, 0.02) < s
    assert HingeMisfitStrain(np.radians(60.0), 0.08, 0.02) == pytest.approx(s / 2)
    assert HingeMisfitStrain(np.radians(60.0), 0.0, 0.02) == float("inf")
    assert TurnAngle(R0, _twist(0.05, 60.0).R_WG_end) == pytest.approx(np.radians(60.0))


def test_a_wide_twist_near_the_attachment_is_rejected_a_far_one_and_a_pull_are_not():
    why = MisfitReason(_twist(0.039, 60.0), HINGE, None, 0.03, 0.4)
    assert "max_hinge_misfit" in why and "60 deg turn" in why
    assert MisfitReason(_twist(0.10, 60.0), HINGE, None, 0.03, 0.4) == ""
    assert MisfitReason(_twist(0.039, 15.0), HINGE, None, 0.03, 0.4) == ""
    pull = Action(np.array([0.039, 0.0, 0.0]), R0, np.array([0.0, 0.03, 0.0]))
    assert MisfitReason(pull, HINGE, None, 0.03, 0.4) == ""
    assert MisfitReason(_twist(0.039, 60.0), None, None, 0.03, 0.4) == ""     # no hinge
    assert MisfitReason(_twist(0.039, 60.0), HINGE, None, 0.03, 0.0) == ""    # off


def test_a_replan_counts_the_turn_from_the_first_grasp():
    # the leaf already turned 40 deg: a further 20 deg twist is a 60 deg turn
    first = _twist(0.05, 40.0)
    more = MakeTwistActions(first.p_WG + first.dp_W, first.R_WG_end, HINGE,
                            [np.radians(20.0)])[0]
    assert MisfitReason(more, HINGE, None, 0.03, 0.5) == ""
    why = MisfitReason(more, HINGE, first.R_WG, 0.03, 0.5)
    assert "60 deg turn" in why


def test_the_veto_rejects_with_a_grouped_reason_and_keeps_the_rest():
    cfg = dc.replace(PlannerConfig(), hinge_error=0.03, max_hinge_misfit=0.4,
                     max_energy_per_node=0.0, arc_lever_reference=0.0)
    cands = []
    for lever in (0.039, 0.045, 0.12):
        c = Candidate(_twist(lever, 60.0), 0)
        c.n_vis, c.energy = 100, 1e-5
        cands.append(c)
    left = _ScoreAndVeto(cfg, HINGE, list(cands), 0.0)
    assert left == [cands[2]]
    counts = RejectionCounts(cands)
    assert len(counts) == 1 and list(counts.values()) == [2]
    assert next(iter(counts)).startswith("a 60 deg turn from a grasp")


def test_a_leaf_seen_far_from_its_branch_assumes_its_unseen_petiole_as_the_hinge_error():
    """The hinge error of the veto is the larger of ``hinge_error`` and
    the unseen petiole: a 45 deg twist 8.4 cm from the estimate passes at
    3 cm and is vetoed when the leaf is seen 5 cm from the branch."""
    cfg = dc.replace(PlannerConfig(), hinge_error=0.03, max_hinge_misfit=0.4,
                     max_energy_per_node=0.0, arc_lever_reference=0.0)
    c = Candidate(_twist(0.084, 45.0), 0)
    c.n_vis, c.energy = 100, 1e-5
    assert _ScoreAndVeto(cfg, HINGE, [c], 0.0) == [c]
    assert _ScoreAndVeto(cfg, HINGE, [c], 0.0, hinge_error_m=0.05) == []
    assert "at hinge_error 5 cm" in c.reason


def test_the_unseen_petiole_is_the_hinge_to_leaf_distance():
    from lmap_drake.planning.attachment import UnseenPetiole
    u, v = np.meshgrid(np.arange(0, 0.1, 0.003), np.arange(0, 0.05, 0.003))
    blade = np.c_[0.04 + u.ravel(), v.ravel(), np.zeros(u.size)]
    speck = np.array([[0.001, 0.0, 0.0]])     # a lone leaf point at the hinge
    assert UnseenPetiole(np.vstack([blade, speck]), np.zeros(3)) == pytest.approx(0.04)
