"""``DeformationPrediction``: the leaf deformation model (paper Sec. III-B)
as a Drake LeafSystem (thin shell around ``lmap_drake.deformation``).

Input ports:

- ``scene_estimate`` (abstract ``SceneEstimate``): leaf points
  ``semantic.leaf_points_W`` and branch points ``semantic.branch_points_W``
  plus, when the branch was completed, ``branch.samples_W`` (all in the
  world frame W, metres).
- ``actions`` (abstract ``list[Action]``): candidate actions, each a grasp
  pose (``p_WG`` m, ``R_WG``) and a gripper displacement ``dp_W`` (m) in W.

Output port:

- ``predictions`` (abstract ``list[PredictedDeformation]``), one per
  action in input order: rest and deformed graph nodes (W, m), every leaf
  point deformed (W, m), the minimised ARAP energy, iteration count.
  Computed on demand and cached by Drake until an input changes. An action
  whose grasp cannot be modelled (off the leaf, leaf part not attached to
  the branch) gets an ``UnmodelledGrasp`` naming why (the planner rejects
  it with that reason; ``skip_unmodelled=False`` raises instead); an
  unusable scene (no leaf, no branch, no grasp modelled) raises
  ``DeformationError``, rather than returning a silent guess.

Parameters come from ``DeformationConfig``. The per-grasp factorisations are
heavy objects: the most recent scene's ones are kept as an attribute of the
system (keyed by the input data), never in the Context.
"""
from __future__ import annotations

import hashlib

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from lmap_drake.deformation.action import Action, GroupActionsByGrasp
from lmap_drake.deformation.graph import BuildLeafGraph, LeafGraph
from lmap_drake.deformation.action import DeformationError
from lmap_drake.deformation.predict import (
    PredictedDeformation, GraspSolution, PrepareGrasp, SolveGrasp, UnmodelledGrasp)
from lmap_drake.deformation.config import DeformationConfig
from lmap_drake.types import SceneEstimate, SemanticScene


def SceneDeformationPoints(scene: SceneEstimate) -> tuple[np.ndarray, np.ndarray]:
    """(leaf_points_W, branch_points_W) the deformation graph is built from:
    the segmented leaf (plus ``leaf_attachment_W``, a virtual petiole, at
    the end), and the segmented branch plus the completed branch's surface
    samples when present."""
    leaf = np.vstack([np.asarray(scene.semantic.leaf_points_W, float).reshape(-1, 3),
                      np.asarray(scene.leaf_attachment_W, float).reshape(-1, 3)])
    branch = [np.asarray(scene.semantic.branch_points_W, float).reshape(-1, 3)]
    if scene.branch is not None:
        branch.append(np.asarray(scene.branch.samples_W, float).reshape(-1, 3))
    return leaf, np.vstack(branch)


class DeformationPrediction(LeafSystem):
    """SceneEstimate + list[Action] -> list[PredictedDeformation]; see the
    module docstring for ports, frames and units."""

    def __init__(self, config: DeformationConfig | None = None, dense: bool = True,
                 skip_unmodelled: bool = True):
        super().__init__()
        self._skip_unmodelled = skip_unmodelled
        self._config = config if config is not None else DeformationConfig()
        self._dense = dense
        self._scene_key: bytes | None = None
        self._leaf_graph: LeafGraph | None = None
        self._grasps: dict[bytes, GraspSolution] = {}
        self.DeclareAbstractInputPort(
            "scene_estimate", AbstractValue.Make(SceneEstimate(semantic=SemanticScene())))
        self.DeclareAbstractInputPort("actions", AbstractValue.Make(list()))
        self.DeclareAbstractOutputPort(
            "predictions", lambda: AbstractValue.Make(list()), self._calc_predictions)

    @property
    def config(self) -> DeformationConfig:
        return self._config

    def _leaf_graph_for(self, scene: SceneEstimate) -> LeafGraph:
        leaf, branch = SceneDeformationPoints(scene)
        h = hashlib.sha1(leaf.tobytes())
        h.update(b"|")
        h.update(branch.tobytes())
        key = h.digest()
        if key != self._scene_key or self._leaf_graph is None:
            self._leaf_graph = BuildLeafGraph(leaf, branch, self._config)
            self._grasps = {}
            self._scene_key = key
        return self._leaf_graph

    def Predict(self, scene: SceneEstimate, actions: list[Action]) -> list[PredictedDeformation]:
        """The output calc without a Context (scripts, tests)."""
        if not actions:
            return []
        leaf_graph = self._leaf_graph_for(scene)
        out: list = [None] * len(actions)
        errors = []
        for idx in GroupActionsByGrasp(actions):
            a0 = actions[idx[0]]
            key = a0.grasp_key()
            if key not in self._grasps:
                try:
                    self._grasps[key] = PrepareGrasp(leaf_graph, a0.p_WG, a0.R_WG,
                                                     self._config)
                except DeformationError as err:
                    if not self._skip_unmodelled:
                        raise
                    errors.append(err)
                    for i in idx:
                        out[i] = UnmodelledGrasp(actions[i], str(err))
                    continue
            preds = SolveGrasp(self._grasps[key], [actions[i] for i in idx], self._config,
                               self._dense)
            for i, p in zip(idx, preds):
                out[i] = p
        if errors and all(isinstance(p, UnmodelledGrasp) for p in out):
            raise errors[0]
        return out

    def _calc_predictions(self, context, output):
        scene = self.get_input_port(0).Eval(context)
        actions = self.get_input_port(1).Eval(context)
        output.set_value(self.Predict(scene, list(actions)))
