"""Deformation prediction for a set of actions: graph per grasp, one ARAP
factorisation per grasp, all (direction, distance) actions of the grasp
solved together, dense interpolation. Grasps are independent and run in
parallel threads (the ARAP kernels release the GIL). World frame W, metres."""
from __future__ import annotations

import dataclasses as dc

import numpy as np

from lmap_drake.deformation.action import Action, DeformationError, GroupActionsByGrasp
from lmap_drake.deformation.arap import ArapProblem
from lmap_drake.deformation.graph import (
    FIXED, HANDLE, BuildGraspGraph, BuildLeafGraph, GraspGraph, LeafGraph)
from lmap_drake.deformation.interpolate import DenseInterpolator
from lmap_drake.parallel import DefaultWorkers, ParallelMap  # noqa: F401 (scripts use it)
from lmap_drake.deformation.config import DeformationConfig


@dc.dataclass
class PredictedDeformation:
    """Predicted leaf state after ``action``. ``nodes_W`` (n, 3) rest graph
    nodes and ``node_kind`` (n,) (0 leaf, 1 fixed, 2 handle) are shared by
    the actions of one grasp; ``deformed_nodes_W`` (n, 3); ``leaf_points_W``
    (N, 3) every input leaf point deformed (None if dense output was not
    asked for); ``energy`` the minimised ARAP energy (m^2, weighted);
    ``iterations`` global-local iterations; ``converged`` the relative
    tolerance was met before the iteration cap."""
    action: Action
    nodes_W: np.ndarray
    node_kind: np.ndarray
    deformed_nodes_W: np.ndarray
    leaf_points_W: np.ndarray | None
    energy: float
    iterations: int
    converged: bool


@dc.dataclass
class UnmodelledGrasp:
    """In place of a prediction: the graph cannot model this action's grasp
    (``message`` says why, e.g. the grasped part of the leaf is not
    connected to the branch); the planner rejects the action with it."""
    action: Action
    message: str


@dc.dataclass
class GraspSolution:
    """Everything built once per grasp pose (a heavy object: keep it as a
    system attribute, never in a Context)."""
    graph: GraspGraph
    problem: ArapProblem
    interpolator: DenseInterpolator


def PrepareGrasp(leaf_graph: LeafGraph, p_WG: np.ndarray, R_WG: np.ndarray,
                 config: DeformationConfig, factorization: str = "inverse") -> GraspSolution:
    """Grasp graph, factorised ARAP problem and dense weights for one grasp."""
    g = BuildGraspGraph(leaf_graph, p_WG, R_WG, config)
    problem = ArapProblem(g.nodes_W, g.edges, g.weights, g.num_free, factorization)
    kept = np.zeros(len(leaf_graph.nodes_W), dtype=bool)
    kept[g.base_index[g.base_index >= 0]] = True
    interp = DenseInterpolator(leaf_graph.leaf_points_W, g.nodes_W,
                               kept[leaf_graph.point_node], config.interpolation_neighbors,
                               config.interpolation_radius, config.interpolation_sigma)
    return GraspSolution(g, problem, interp)


def HandleDisplacements(handle_W: np.ndarray, actions: list[Action]) -> np.ndarray:
    """(len(actions), h, 3): each handle node's displacement (m) when the
    gripper moves rigidly from (p_WG, R_WG) to (p_WG + dp_W, R_delta R_WG)."""
    out = np.empty((len(actions),) + np.shape(handle_W))
    for i, a in enumerate(actions):
        rel = handle_W - a.p_WG
        out[i] = a.p_WG + a.dp_W + rel @ a.R_delta.T - handle_W
    return out


def SolveActions(prep: GraspSolution, actions: list[Action], config: DeformationConfig):
    """``ArapResult`` of all ``actions`` (sharing ``prep``'s grasp), solved
    in one batch: fixed nodes stay, handle nodes move rigidly with the
    gripper (``HandleDisplacements``)."""
    g = prep.graph
    u_c = np.zeros((len(actions), g.num_constrained, 3))
    u_c[:, g.num_fixed:] = HandleDisplacements(g.nodes_W[g.num_free + g.num_fixed:], actions)
    return prep.problem.Solve(u_c, config.max_iterations, config.relative_tolerance,
                              method=config.arap_method)


def _Predictions(prep: GraspSolution, actions: list[Action], res, dense: bool):
    g = prep.graph
    dense_W = (prep.interpolator.Apply(g.nodes_W, res.positions_W, res.rotations)
               if dense else [None] * len(actions))
    return [PredictedDeformation(action=a, nodes_W=g.nodes_W, node_kind=g.kind,
                                  deformed_nodes_W=res.positions_W[i], leaf_points_W=dense_W[i],
                                  energy=float(res.energy[i]), iterations=int(res.iterations[i]),
                                  converged=bool(res.converged[i]))
            for i, a in enumerate(actions)]


def SolveGrasp(prep: GraspSolution, actions: list[Action], config: DeformationConfig,
               dense: bool = True) -> list[PredictedDeformation]:
    """Solves all ``actions`` (sharing ``prep``'s grasp) in one batch: fixed
    nodes stay, handle nodes move by each action's dp_W."""
    return _Predictions(prep, actions, SolveActions(prep, actions, config), dense)


def PrepareAndSolveGrasps(leaf_graph: LeafGraph, groups: list[list[Action]],
                          config: DeformationConfig, factorization: str = "inverse",
                          workers: int | None = None, skip_unmodelled: bool = False) -> list:
    """(GraspSolution, ArapResult) per group of actions sharing a grasp
    (``PrepareGrasp`` then ``SolveActions``), groups spread over ``workers``
    threads (default ``DefaultWorkers()``); results in the order of
    ``groups``. With ``skip_unmodelled`` a grasp the graph cannot model
    gives (None, DeformationError) instead of raising."""
    def Run(acts):
        try:
            prep = PrepareGrasp(leaf_graph, acts[0].p_WG, acts[0].R_WG, config, factorization)
        except DeformationError as err:
            if not skip_unmodelled:
                raise
            return None, err
        return prep, SolveActions(prep, acts, config)

    return ParallelMap(Run, groups, workers)


def PredictDeformations(leaf_points_W: np.ndarray, branch_points_W: np.ndarray,
                        actions: list[Action], config: DeformationConfig,
                        dense: bool = True, workers: int | None = None,
                        skip_unmodelled: bool = False) -> list:
    """Predictions for ``actions`` (any order, any number of grasps), in
    the order given; grasps in ``workers`` threads (``PrepareAndSolveGrasps``).
    Raises DeformationError on unusable input; with ``skip_unmodelled`` an
    action whose grasp alone cannot be modelled gets an ``UnmodelledGrasp``
    (it still raises when no grasp can be)."""
    if not actions:
        return []
    leaf_graph = BuildLeafGraph(leaf_points_W, branch_points_W, config)
    out: list[PredictedDeformation | None] = [None] * len(actions)
    idxs = GroupActionsByGrasp(actions)
    groups = [[actions[i] for i in idx] for idx in idxs]
    solved = PrepareAndSolveGrasps(leaf_graph, groups, config, workers=workers,
                                   skip_unmodelled=skip_unmodelled)
    if all(prep is None for prep, _ in solved):
        raise solved[0][1]
    for idx, acts, (prep, res) in zip(idxs, groups, solved):
        preds = ([UnmodelledGrasp(a, str(res)) for a in acts] if prep is None
                 else _Predictions(prep, acts, res, dense))
        for i, p in zip(idx, preds):
            out[i] = p
    return out
