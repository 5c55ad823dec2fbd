"""Shared fixtures of the deformation tests: a synthetic ovate leaf on a
branch and the grasp graph of a tip grasp."""
import numpy as np
import pytest

from lmap_drake.deformation import BuildGraspGraph, BuildLeafGraph
from lmap_drake.deformation.synthetic import OvateLeaf
from leaf_fixtures import R_TIP, TEST_CONFIG


@pytest.fixture(scope="session")
def plant():
    """(leaf_points_W, branch_points_W) of OvateLeaf at 1.5 mm spacing."""
    return OvateLeaf(spacing=0.0015)


@pytest.fixture(scope="session")
def tip_graph(plant):
    """(p_WG, GraspGraph) of a grasp 1 cm inside the leaf tip (R_TIP)."""
    leaf, branch = plant
    lg = BuildLeafGraph(leaf, branch, TEST_CONFIG)
    p = leaf[np.argmax(leaf[:, 0] - 5 * np.abs(leaf[:, 1]))] - [0.01, 0, 0]
    return p, BuildGraspGraph(lg, p, R_TIP, TEST_CONFIG)
