"""A small dense Levenberg-Marquardt solver on the normal equations.

Calibration problems have a few hundred parameters and many thousand residuals; MINPACK's QR
(``scipy.optimize.least_squares(method="lm")``) spends most of its time factorising the tall
Jacobian, while the normal equations ``J^T J`` are tiny. Columns are scaled by the square root
of the diagonal of ``J^T J`` (Marquardt's scaling), which makes the steps independent of the
parameters' units (pixels, radians, metres).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse

from sea3d._typing import FloatArray

# fun(x, want_jac) -> (residuals (M,), Jacobian (M, P) dense or scipy.sparse, or None)
ResidualFn = Callable[[FloatArray, bool], tuple[FloatArray, Any]]


@dataclass(frozen=True, kw_only=True, eq=False)
class LMResult:
    """Outcome of :func:`levenberg_marquardt`.

    Attributes:
        x: ``(P,)`` the solution.
        residuals: ``(M,)`` residuals at ``x``.
        jac: ``(M, P)`` Jacobian at ``x`` (as ``fun`` returned it: dense or sparse).
        iterations: accepted steps taken.
        converged: a tolerance was met (False: iteration limit or a stalled damping).
        message: why it stopped.
    """

    x: FloatArray
    residuals: FloatArray
    jac: Any
    iterations: int
    converged: bool
    message: str

    @property
    def cost(self) -> float:
        """Sum of squared residuals."""
        return float(self.residuals @ self.residuals)


def _normal_equations(J: Any, r: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``J^T J`` and ``J^T r``. Calibration Jacobians are block-sparse (each view touches its own
    pose and the shared parameters only), so the product goes through a sparse matrix: faster
    than a dense product and free of BLAS thread start-up on small problems."""
    Js: Any = J if scipy.sparse.issparse(J) else scipy.sparse.csr_matrix(J)
    JT = Js.T.tocsr()
    return np.asarray((JT @ Js).toarray()), np.asarray(JT @ r)


def levenberg_marquardt(fun: ResidualFn, x0: FloatArray, *, max_iter: int = 100,
                        ftol: float = 1e-12, xtol: float = 1e-12,
                        lambda0: float = 1e-4) -> LMResult:
    """Minimise ``sum(fun(x)[0] ** 2)``.

    Args:
        fun: ``fun(x, want_jac) -> (residuals (M,), jacobian (M, P) or None)``; the Jacobian
            may be a dense array or a ``scipy.sparse`` matrix.
        x0: ``(P,)`` start.
        max_iter: most accepted steps.
        ftol: stop when the relative cost decrease of a step is below this.
        xtol: stop when the scaled step is below this relative to the scaled ``x``.
        lambda0: initial damping (relative to the scaled normal matrix's unit diagonal).

    Returns:
        An :class:`LMResult`; it never raises on non-convergence.
    """
    x = np.asarray(x0, dtype=np.float64).copy()
    r, J = fun(x, True)
    assert J is not None
    cost = float(r @ r)
    lam = lambda0
    it = 0
    message = "iteration limit reached"
    converged = False
    n = x.size
    while it < max_iter:
        A, g = _normal_equations(J, r)
        d = np.sqrt(np.diag(A))
        d[d == 0] = 1.0
        As = A / d[:, None] / d[None, :]
        gs = g / d
        accepted = False
        while lam < 1e16:
            try:
                # LU rather than Cholesky: OpenBLAS's threaded potrf is slow on small matrices
                # when the cores are busy (measured 22 ms against 2 ms for 258 x 258).
                step = -np.linalg.solve(As + lam * np.eye(n), gs) / d
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            if not np.all(np.isfinite(step)):
                lam *= 10.0
                continue
            x_new = x + step
            r_new, _ = fun(x_new, False)
            cost_new = float(r_new @ r_new) if np.all(np.isfinite(r_new)) else math.inf
            if cost_new < cost:
                accepted = True
                break
            lam *= 10.0
        if not accepted:
            message = "no step lowers the cost (converged or stalled)"
            converged = True
            break
        it += 1
        decrease = cost - cost_new
        small_step = float(np.linalg.norm(step * d)) <= xtol * (
            float(np.linalg.norm(x * d)) + xtol)
        x = x_new
        r, J = fun(x, True)
        assert J is not None
        cost = float(r @ r)
        lam = max(lam / 10.0, 1e-12)
        if decrease <= ftol * max(cost, 1e-300) or small_step:
            message = "relative cost decrease below ftol" if not small_step else (
                "step below xtol")
            converged = True
            break
    return LMResult(x=x, residuals=r, jac=J, iterations=it, converged=converged,
                    message=message)
