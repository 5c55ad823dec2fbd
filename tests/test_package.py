"""lmap_drake/__init__.py: what importing the package sets up."""
import logging

import lmap_drake  # noqa: F401  (installs the trimesh log filter)


def test_trimesh_short_sample_notes_are_dropped_other_messages_pass(caplog):
    with caplog.at_level(logging.WARNING):
        logging.getLogger("trimesh").warning("only got 1487/1500 samples!")
        logging.getLogger("trimesh").warning("mesh is not watertight")
    msgs = [r.getMessage() for r in caplog.records]
    assert "mesh is not watertight" in msgs
    assert not any(m.startswith("only got") for m in msgs)
