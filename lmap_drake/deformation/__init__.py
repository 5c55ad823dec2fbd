"""Leaf deformation prediction (paper Sec. III-B): embedded deformation
graph, batched ARAP solve, dense interpolation. World frame W, metres."""
from lmap_drake.deformation.action import (
    Action, DeformationError, GroupActionsByGrasp, MakeActions, PullDirections)
from lmap_drake.deformation.graph import (
    GraspGraph, LeafGraph, BuildGraspGraph, BuildLeafGraph, HandleGrid)
from lmap_drake.deformation.arap import ArapProblem, ArapResult
from lmap_drake.deformation.interpolate import DenseInterpolator
from lmap_drake.deformation.predict import (
    PredictedDeformation, GraspSolution, PredictDeformations, PrepareGrasp, SolveGrasp)

__all__ = [
    "Action", "DeformationError", "GroupActionsByGrasp", "MakeActions", "PullDirections",
    "GraspGraph", "LeafGraph", "BuildGraspGraph", "BuildLeafGraph", "HandleGrid",
    "ArapProblem", "ArapResult", "DenseInterpolator",
    "PredictedDeformation", "GraspSolution", "PredictDeformations", "PrepareGrasp",
    "SolveGrasp",
]
