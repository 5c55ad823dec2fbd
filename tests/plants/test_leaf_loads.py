"""Every FEM leaf the robot touches, grasped or only brushed, gets its
worst loads recorded (``episode.json`` ``leaf_loads``)."""
import pytest

from lmap_drake.plants.config import OutcomeConfig
from lmap_drake.plants.outcome import LeafLoadRows, OutcomeSample


def _Sample(t, loads, held=None):
    return OutcomeSample(1.0, 0.0, 0.0, 0.0, t=t, leaf_loads=loads, grasped_leaf=held)


def test_leaf_rows_keep_each_leafs_worst_and_say_how_it_was_touched():
    samples = [_Sample(0.0, {0: (1.00, 0.1, 0.0), 1: (1.00, 0.2, 0.0), 2: (1.0, 0.0, 0.0)}),
               _Sample(0.05, {0: (1.02, 3.0, 0.4), 1: (1.01, 2.5, 0.3), 2: (1.0, 0.1, 0.0)}, 0),
               _Sample(0.10, {0: (1.03, 2.0, 0.2), 1: (1.12, 16.0, 0.0), 2: (1.0, 0.0, 0.0)})]
    rows = LeafLoadRows(samples, OutcomeConfig())
    assert [r["leaf"] for r in rows] == [0, 1, 2]
    held, brushed, untouched = rows
    assert (held["grasped"], held["touched"], held["brushed"]) == (True, True, False)
    assert held["max_petiole_force"] == 3.0 and held["max_petiole_force_t"] == 0.05
    assert held["max_robot_contact_force"] == 0.4 and not held["damaged"]
    assert (brushed["grasped"], brushed["brushed"]) == (False, True)
    assert brushed["max_strain_percentile"] == pytest.approx(1.12)
    assert brushed["damaged"]            # 16 N > 15 N (and a 1.12 stretch)
    assert not (untouched["touched"] or untouched["brushed"] or untouched["damaged"])
    assert LeafLoadRows([], OutcomeConfig()) == []


def test_a_brushed_fem_leaf_is_recorded_and_stays_under_the_planners_bound():
    """The closed gripper's pads come in along the single plant's FEM leaf's
    normal until their tips reach its rest surface, 11 cm out on the blade,
    and back out (``studies.brush``): the plant world records the robot's
    contact force on that leaf and the leaf as brushed, not grasped; the
    planner predicts a push within its allowance there and a petiole load
    above the one measured."""
    from lmap_drake.planning.robot_checks import BrushAllowance
    from lmap_drake.studies.brush import BrushStudyOptions, RunBrushStudy
    (row,) = RunBrushStudy(BrushStudyOptions(points=[[0.11, 0.0]], depths=[0.0], hold=0.2),
                           log=lambda _: None)
    assert "error" not in row, row
    assert row["robot_contact_force_N"] > 0.0
    assert 0.005 < row["predicted_push"] <= BrushAllowance(row["lever"], 0.01)
    assert row["petiole_force_before_N"] < row["petiole_force_N"] <= row["predicted_N"] < 5.0
    assert not row["damaged"]
