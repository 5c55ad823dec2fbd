"""``ShapeCompletion``: branch completion + scene-consistent shape completion
(paper Sec. III-A) as a Drake LeafSystem (thin shell around
``lmap_drake.shape.completion.CompleteScene``).

Input ports:

- ``semantic_scene`` (abstract ``SemanticScene``): segmented points in the
  world frame W (metres) and the camera pose ``X_WC`` they came from (the
  camera centre is the origin of the free-space rays).

Output ports:

- ``scene_estimate`` (abstract ``SceneEstimate``): the completed branch
  (mesh + samples, W) and fruit (mesh, ``X_WO`` Sim(3) object-to-world,
  latent, centre, peduncle axis, ``sdf_W`` callable, loss trace). Computed
  on demand and cached by Drake until the input changes (it depends on the
  input port only, not on time or state).
- ``plant_estimate`` (abstract ``PlantEstimate``): every fruit instance
  completed on its own (``CompletePlant``; the other fruits' points count as
  outside it) and the branches; for plants with several fruits
  (``planner.targets: all``). Computed only when evaluated.

With ``focus_port=True`` an input ``target_center`` (abstract: the centre
of the fruit being revealed, W, m, shape (3,), or None) restricts
``plant_estimate`` to the fruit instances within 8 cm of it (the
re-estimate of the target; ``CompletePlant``'s ``focus_W``); None completes
every fruit.

The DeepSDF decoder is loaded once in the constructor (from
``ShapeConfig.weights_file``, or passed in) and kept as an attribute, not
Context state. ``reestimate=True`` (or the flag ``"reestimate"`` in the
input's ``flags``) uses the re-estimation weights after the leaf action
(``shape.ssc.reestimate_*``).
"""
from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from lmap_drake.shape.completion import CompletePlant, CompleteScene, FitMemo
from lmap_drake.shape.config import ReestimateConfig, ShapeConfig, SscConfig
from lmap_drake.shape.deepsdf import LoadDecoder
from lmap_drake.types import PlantEstimate, SceneEstimate, SemanticScene


class ShapeCompletion(LeafSystem):
    """SemanticScene -> SceneEstimate; see the module docstring."""

    def __init__(self, cfg: ShapeConfig | None = None, decoder=None, mean_latent=None,
                 reestimate: bool = False, method: str | None = None,
                 focus_port: bool = False, fit_memo: FitMemo | None = None):
        super().__init__()
        self.cfg = cfg or ShapeConfig()
        # earlier fruit fits, reused for a fruit seen again unchanged (shared
        # by the episode's rebuilt diagrams; see FitMemo)
        self.fit_memo = fit_memo if fit_memo is not None else FitMemo(
            tolerance=self.cfg.reuse_tolerance)
        if decoder is None and (method or getattr(self.cfg, "method", "ssc")) != "supeps":
            decoder, mean_latent, _ = LoadDecoder(self.cfg.weights_file,
                                                  getattr(self.cfg, "mean_latent_file", "")
                                                  or None)
        self.decoder, self.mean_latent = decoder, mean_latent
        self.reestimate = reestimate
        self.method = method or getattr(self.cfg, "method", "ssc")
        self.last_timings: dict = {}
        self._in = self.DeclareAbstractInputPort("semantic_scene",
                                                 AbstractValue.Make(SemanticScene()))
        self.DeclareAbstractOutputPort(
            "scene_estimate", lambda: AbstractValue.Make(SceneEstimate(SemanticScene())),
            self._calc, prerequisites_of_calc={self._in.ticket()})
        plant_deps = {self._in.ticket()}
        self._focus = None
        if focus_port:
            self._focus = self.DeclareAbstractInputPort("target_center",
                                                        AbstractValue.Make(object()))
            plant_deps.add(self._focus.ticket())
        # the focus comes from the controller's state, which changes every
        # tick, and a view segmented again is a new object with the same
        # contents: the last result is kept for an unchanged view (same
        # contents, ``SemanticScene.Fingerprint``) and focus
        self._plant_memo: tuple | None = None
        self.DeclareAbstractOutputPort(
            "plant_estimate", lambda: AbstractValue.Make(PlantEstimate(SemanticScene())),
            self._calc_plant, prerequisites_of_calc=plant_deps)

    def params(self, reestimate: bool) -> SscConfig:
        return ReestimateConfig(self.cfg.ssc) if reestimate else self.cfg.ssc

    def _calc(self, context, output):
        sem: SemanticScene = self._in.Eval(context)
        re = self.reestimate or "reestimate" in sem.flags
        timings = {}
        est = CompleteScene(sem, self.decoder, self.mean_latent, self.params(re), self.method,
                            self.cfg.free_space_voxel, self.cfg.branch, timings)
        self.last_timings = timings
        output.set_value(est)

    def _calc_plant(self, context, output):
        sem: SemanticScene = self._in.Eval(context)
        focus = None
        if self._focus is not None and self._focus.HasValue(context):
            value = self._focus.Eval(context)
            if value is not None and np.size(value) == 3:
                focus = np.asarray(value, float).reshape(3)
        key = (sem.Fingerprint(), None if focus is None else tuple(np.round(focus, 4)))
        if self._plant_memo is not None and self._plant_memo[0] == key:
            output.set_value(self._plant_memo[1])
            return
        re = self.reestimate or "reestimate" in sem.flags
        timings = {}
        est = CompletePlant(sem, self.decoder, self.mean_latent, self.params(re), self.method,
                            self.cfg.free_space_voxel, self.cfg.branch,
                            min_fruit_points=self.cfg.min_fruit_points, timings=timings,
                            leaf_split_angle_deg=self.cfg.leaf_split_angle_deg,
                            focus_W=focus, memo=self.fit_memo)
        self.last_timings = timings
        self._plant_memo = (key, est)
        output.set_value(est)
