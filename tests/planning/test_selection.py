"""lmap_drake/planning/selection.py: pure helpers (the stages themselves are
tested through test_ik_collision_selection.py and the episodes)."""
from lmap_drake.planning.selection import GroupReasons


def test_reasons_are_grouped_by_wording_with_their_numbers_as_ranges():
    text = GroupReasons(["robot self-collision"] * 3 + [
        "predicted visibility 0.93 not above the current 0.97 + 0.05",
        "predicted visibility 0.61 not above the current 0.97 + 0.05",
        "predicted visibility 0.8 not above the current 0.97 + 0.05",
        "energy 1.2e-3 above the cap 1e-3", "IK failed", ""])
    assert text == ("robot self-collision: 3, "
                    "predicted visibility 0.61-0.93 not above the current 0.97 + 0.05: 3, "
                    "energy 1.2e-3 above the cap 1e-3: 1, IK failed: 1, unknown: 1")
    # no placeholder reaches the user
    assert "#" not in text and "\0" not in text


def test_a_pull_pushing_the_leaf_back_toward_its_fruit_is_checked_with_the_leaf_shifted_whole():
    from types import SimpleNamespace

    import numpy as np

    from lmap_drake.deformation.action import Action
    from lmap_drake.planning.config import PlannerConfig
    from lmap_drake.planning.selection import PushedBackLeaf, _LeafChecks

    c, r = np.array([0.5, 0.0, 0.3]), 0.03                  # the fruit, 1.5 cm behind the leaf
    sdf = lambda q: np.linalg.norm(np.asarray(q) - c, axis=1) - r  # noqa: E731
    g = np.mgrid[-0.03:0.031:0.005, 0:1, -0.03:0.031:0.005].reshape(3, -1).T
    leaf = c + [0.0, -0.045, 0.0] + g                        # a blade facing the camera
    p_WC, p_WG = np.array([0.5, -0.6, 0.3]), c + [0.0, -0.045, 0.0]
    ctx = SimpleNamespace(leaf_W=leaf, p_WC=p_WC, fruit_sdf=sdf, fruit_box=None,
                          branch_distance=None)
    checks = _LeafChecks(ctx, PlannerConfig())
    back_up = Action(p_WG, np.eye(3), dp_W=0.04 * np.array([0.0, 0.5, np.sqrt(0.75)]))
    ray = (p_WG - p_WC) / np.linalg.norm(p_WG - p_WC)
    shifted, s = PushedBackLeaf(leaf, p_WC, p_WG, back_up.dp_W)
    assert np.isclose(s, back_up.dp_W @ ray) and np.isclose(s, 0.02)
    np.testing.assert_allclose(shifted - leaf, np.tile(s * ray, (len(leaf), 1)))
    # the graph's kind of prediction (the blade lifted over the fruit) passes;
    # the blade shoved back by the push's 2 cm is on the fruit
    assert checks.Reason(leaf + [0.0, 0.0, 0.04]) == ""
    why = checks.PushedBackReason(back_up)
    assert why.startswith("leaf-fruit (") and why.endswith("if pushed back 2.0 cm")
    # toward the camera, or a turn about the hinge: nothing is shifted
    toward = Action(p_WG, np.eye(3), dp_W=0.04 * np.array([0.0, -0.5, np.sqrt(0.75)]))
    assert PushedBackLeaf(leaf, p_WC, p_WG, toward.dp_W)[0] is None
    assert checks.PushedBackReason(toward) == ""
    arc = Action(p_WG, np.eye(3), family="arc", pivot_W=c + [0.0, -0.045, 0.08],
                 axis_W=[1.0, 0.0, 0.0], angle=0.5)
    assert arc.dp_W[1] > 0.01 and checks.PushedBackReason(arc) == ""
    # the shifted leaf is checked against the fruits only: shifted whole, the
    # blade's base would enter the branch it hangs from (check_leaf_branch)
    import dataclasses as dc
    stem = SimpleNamespace(leaf_W=leaf, p_WC=p_WC, fruit_sdf=lambda q: np.full(len(q), 1.0),
                           fruit_box=None, branch_box=None,
                           branch_distance=lambda q: np.abs(np.asarray(q)[:, 1] + 0.027))
    checks = _LeafChecks(stem, dc.replace(PlannerConfig(), check_leaf_branch=True))
    assert checks.Reason(shifted).startswith("leaf-branch (")
    assert checks.PushedBackReason(back_up) == ""
