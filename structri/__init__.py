"""Structural Triangulation (Chen et al., ECCV 2022): closed-form bone-length-constrained triangulation.

Batched, jit-compiled solvers (:func:`structural_triangulation` and the LS / LEM / Lagrangian baselines
in the same API), per-frame :class:`Status` codes, bone-length estimation, and a certified float64
constrained reference built on optimistix (:func:`constrained_reference`). The loop-based NumPy port of
the official code, a test and benchmark oracle, is the submodule :mod:`structri.numpy_reference` (not
re-exported here); the virtual-camera and real-Shelf experiments live in :mod:`experiments.structri_study`.
"""

from importlib.metadata import version as _version

from ._reference import constrained_reference as constrained_reference
from ._reference import reduced_objective as reduced_objective
from ._reference import ReferenceResult as ReferenceResult
from ._solver import estimate_bone_lengths as estimate_bone_lengths
from ._solver import lagrangian_triangulation as lagrangian_triangulation
from ._solver import lem_triangulation as lem_triangulation
from ._solver import ls_triangulation as ls_triangulation
from ._solver import projection_matrices as projection_matrices
from ._solver import reduced_problem as reduced_problem
from ._solver import structural_triangulation as structural_triangulation
from ._solver import Status as Status
from ._solver import StructriResult as StructriResult

__version__ = _version("mvmocap")
