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
