"""lmap_drake: safe leaf manipulation (LMAP) and scene-consistent shape
completion (SSC) for occluded fruits, as a Drake systems-diagram application."""

__version__ = "0.1.0"
