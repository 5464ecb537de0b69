"""Structural Triangulation (Chen et al., ECCV 2022): closed-form bone-length-constrained triangulation.

Batched, jit-compiled solvers (:func:`structural_triangulation` and the LS / LEM / Lagrangian baselines
in the same API), per-frame :class:`Status` codes, bone-length estimation, and a certified float64
constrained reference built on optimistix (:func:`constrained_reference`).
"""

from ._numpy_reference import numpy_lem_triangulation as numpy_lem_triangulation
from ._numpy_reference import numpy_structural_triangulation as numpy_structural_triangulation
from ._numpy_reference import numpy_structural_triangulation_frames as numpy_structural_triangulation_frames
from ._reference import ReferenceResult as ReferenceResult
from ._reference import constrained_reference as constrained_reference
from ._reference import reduced_objective as reduced_objective
from ._solver import Status as Status
from ._solver import StructriResult as StructriResult
from ._solver import estimate_bone_lengths as estimate_bone_lengths
from ._solver import lagrangian_triangulation as lagrangian_triangulation
from ._solver import lem_triangulation as lem_triangulation
from ._solver import ls_triangulation as ls_triangulation
from ._solver import projection_matrices as projection_matrices
from ._solver import reduced_problem as reduced_problem
from ._solver import structural_triangulation as structural_triangulation

__all__ = [
    "ReferenceResult", "Status", "StructriResult", "constrained_reference", "estimate_bone_lengths",
    "lagrangian_triangulation", "lem_triangulation", "ls_triangulation", "numpy_lem_triangulation",
    "numpy_structural_triangulation", "numpy_structural_triangulation_frames", "projection_matrices",
    "reduced_objective", "reduced_problem", "structural_triangulation",
]
