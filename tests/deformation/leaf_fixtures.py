"""Constants shared by the deformation tests (fixtures: conftest.py)."""
import numpy as np

from lmap_drake.deformation.config import DeformationConfig

# Gripper approaching the leaf tip along -x, closing along z (leaf normal).
R_TIP = np.column_stack([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])
TEST_CONFIG = DeformationConfig(max_iterations=150, relative_tolerance=1e-5)
