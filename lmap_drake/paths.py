"""Locations of the repository's data folders (models, scenarios)."""
from __future__ import annotations

from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
MODELS_DIR = REPO_ROOT / "models"
DIAGRAMS_DIR = REPO_ROOT / "diagrams"
DEFAULT_SCENARIO_FILE = DIAGRAMS_DIR / "default.yaml"
DEFAULT_SCENARIO_NAME = "Defaults"
PACKAGE_XML = MODELS_DIR / "package.xml"
MODELS_PACKAGE = "lmap_drake_models"
