"""Thin Drake LeafSystems, one file per pipeline stage."""
