"""lmap_drake: safe leaf manipulation (LMAP) and scene-consistent shape
completion (SSC) for occluded fruits, as a Drake systems-diagram application."""

import os as _os

# Many small dense products (ARAP, IK, SDF batches): multi-threaded OpenBLAS
# is much slower for them on a shared 2-core machine (measured: a 594 x 594
# inverse 4 s instead of 0.04 s). Users can override it in the environment.
_os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def _DropShortSampleNotes(record) -> bool:
    """trimesh's ``sample_surface_even`` logs "only got N/M samples!" when
    its rejection sampling keeps fewer points than asked (a pepper mesh
    from a file, a small estimate). Every caller here uses what it gets, so
    the note only reaches the terminal (Python's last-resort handler) as a
    stray line between the progress lines; other trimesh messages pass."""
    return not str(record.msg).startswith("only got ")


def _DropDeformableMeshcatNote(record) -> bool:
    """Drake 1.51's MeshcatVisualizer skips deformable geometry, and says so
    for the FEM leaf's tetrahedral ``.vtk`` as "only supports Mesh/Convex
    specifications which use .obj ... (e.g., .stl, etc.) will not be
    visualized" on every run. This application has no other non-OBJ mesh
    (the robot is primitives, file peppers are re-exported as OBJ), and its
    ``scene.html`` adds the leaf as snapshots itself, so the note only
    misleads; other Drake messages pass."""
    return "only supports Mesh/Convex specifications" not in str(record.msg)


import logging as _logging

_logging.getLogger("trimesh.sample").addFilter(_DropShortSampleNotes)
_logging.getLogger("drake").addFilter(_DropDeformableMeshcatNote)

__version__ = "0.1.0"
