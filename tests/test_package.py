"""lmap_drake/__init__.py: what importing the package sets up."""
import logging

import trimesh

import lmap_drake  # noqa: F401  (installs the trimesh log filter)


def test_trimesh_short_sample_notes_are_dropped_other_messages_pass(caplog):
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    with caplog.at_level(logging.WARNING):
        # 5000 points 5 cm apart do not fit on 6 m^2: trimesh keeps fewer
        pts, _ = trimesh.sample.sample_surface_even(box, 5000, radius=0.05, seed=0)
        logging.getLogger("trimesh.sample").warning("another note")
    assert len(pts) < 5000
    msgs = [r.getMessage() for r in caplog.records]
    assert "another note" in msgs
    assert not any(m.startswith("only got") for m in msgs), msgs


def test_meshcat_note_on_the_deformable_leaf_is_dropped_other_drake_messages_pass(caplog):
    """The plant station with Meshcat, initialised: Drake's "only supports
    Mesh/Convex ... .obj" note about the FEM leaf's .vtk does not reach the
    user; another Drake warning does."""
    from pydrake.geometry import Meshcat
    from pydrake.systems.analysis import Simulator
    from lmap_drake.plants.plant_station import MakePlantStation
    from lmap_drake.scenario import LoadDefaultScenario
    with caplog.at_level(logging.WARNING):
        station = MakePlantStation(LoadDefaultScenario(), Meshcat())
        Simulator(station).Initialize()
        logging.getLogger("drake").warning("another drake note")
    msgs = [r.getMessage() for r in caplog.records]
    assert "another drake note" in msgs
    assert not any("Mesh/Convex" in m for m in msgs), msgs
