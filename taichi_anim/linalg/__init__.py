"""Matrix-free linear solvers for the implicit step: they see a system only through `apply` (row i of
A p) and `precondition` (row i of the block-diagonal inverse), like `taichi.linalg.LinearOperator`."""

from .. import validate
from .base import LinearSolver, LinearSolveResult, LinearSolverKind
from .cg import LinearSolverCG
from .jacobi import LinearSolverJacobi


def make_linear_solver(kind, **options) -> LinearSolver:
    """ "jacobi", "cg" or "pcg" (CG with the block-Jacobi preconditioner), with tol and max_iterations."""
    if not isinstance(kind, LinearSolverKind):
        validate.choice("linear_solver", kind, [k.value for k in LinearSolverKind])
        kind = LinearSolverKind(kind)
    if kind == LinearSolverKind.JACOBI:
        return LinearSolverJacobi(**options)
    return LinearSolverCG(preconditioned=kind == LinearSolverKind.PCG, **options)


__all__ = [
    "LinearSolveResult",
    "LinearSolver",
    "LinearSolverCG",
    "LinearSolverJacobi",
    "LinearSolverKind",
    "make_linear_solver",
]
