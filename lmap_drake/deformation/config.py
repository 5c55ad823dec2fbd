"""Configuration of the deformation prediction (embedded deformation graph
and ARAP solve, paper Sec. III-B): the ``deformation`` section of the
scenario. Lengths in metres."""
# (no ``from __future__ import annotations``: Drake's ``yaml_load_typed``
# reads the field types)

import dataclasses as dc

from lmap_drake.config_checks import CheckRules


@dc.dataclass
class DeformationConfig:
    """Embedded deformation graph and ARAP solve (Sec. III-B). Lengths in m.

    ``vein_weights``: edge weights for two / one / no midrib endpoints.
    Leaf-to-branch edges use ``leaf_branch_edge_radius`` and
    ``leaf_branch_weight`` (the authors' code: 16 mm, 100; set them to
    ``edge_radius`` and 1 for the paper's single radius rule). A grasp more
    than ``max_grasp_distance`` from the leaf is an error; a handle with no
    leaf node within ``edge_radius`` is tied to its
    ``handle_fallback_neighbors`` nearest leaf nodes. Dense points follow
    their ``interpolation_neighbors`` nearest nodes (within
    ``interpolation_radius``) with Gaussian RBF weights of width
    ``interpolation_sigma``, each node applying its ARAP rotation.
    ``arap_method``: "lbfgs" (L-BFGS with the Laplacian as initial Hessian,
    longer pulls of a direction starting from the shorter one's solution;
    the default) or "plain" (textbook global-local iterations from the
    Laplacian solve); both stop when the relative energy decrease of an
    iteration falls below ``relative_tolerance``."""
    voxel_size: float = 0.005  # m: leaf and branch points become one graph node per voxel
    edge_radius: float = 0.008  # m: nodes closer than this share an edge (not leaf-branch pairs)
    # m: leaf nodes within this of the leaf's PCA centre line are midrib (vein) nodes
    vein_distance: float = 0.012
    vein_weights: list[float] = dc.field(default_factory=lambda: [3.0, 2.0, 1.0])
    handle_grid: int = 5  # the gripper handle is a handle_grid x handle_grid square of nodes
    handle_size: float = 0.025  # m, side of that square, in the pads' plane, centred on the grasp
    # m: branch nodes within this of a leaf node are the graph's fixed nodes
    fixed_branch_distance: float = 0.05
    max_iterations: int = 300  # cap on ARAP iterations per solve
    relative_tolerance: float = 1e-5
    arap_method: str = "lbfgs"
    leaf_branch_edge_radius: float = 0.016
    leaf_branch_weight: float = 100.0
    branch_edge_weight: float = 1.0  # weight of branch-branch edges (between fixed nodes)
    max_grasp_distance: float = 0.02
    handle_fallback_neighbors: int = 3
    interpolation_neighbors: int = 8
    interpolation_radius: float = 0.05
    interpolation_sigma: float = 0.005



_RULES = {
    "voxel_size": ">0",
    "edge_radius": ">0",
    "vein_distance": ">=0",
    "vein_weights": "3x>0",
    "handle_grid": ">=1",
    "handle_size": ">0",
    "fixed_branch_distance": ">0",
    "max_iterations": ">=1",
    "relative_tolerance": ">0",
    "leaf_branch_edge_radius": ">0",
    "leaf_branch_weight": ">0",
    "max_grasp_distance": ">0",
    "handle_fallback_neighbors": ">=1",
    "interpolation_neighbors": ">=1",
    "interpolation_radius": ">0",
    "interpolation_sigma": ">0",
}
_ENUMS = {"arap_method": ("lbfgs", "plain")}


def ValidateDeformationConfig(cfg: DeformationConfig, path: str = "deformation") -> None:
    """Raises ``ConfigError`` (key path, what is wrong) on a bad value."""
    CheckRules(cfg, path, _RULES, _ENUMS)
