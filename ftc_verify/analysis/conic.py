r"""The analysis LMIs as conic programs, handed to Clarabel directly.

The blocks of :mod:`ftc_verify.analysis.lmi` are affine in the decision variables. This
module evaluates the same :func:`~ftc_verify.analysis.lmi.lyapunov_block` on
:class:`Affine` objects -- matrices whose entries are affine functions
:math:`M(x) = M_0 + \sum_k x_k M_k` of a vector :math:`x`, stored as the array
``const`` (:math:`M_0`) and ``lin`` (the :math:`M_k` stacked on a last axis) -- and
writes the result in Clarabel's standard form

.. math::

    \min_x c^T x \quad \text{s.t.} \quad A x + s = b, \; s \in \mathcal K,

with :math:`\mathcal K` a product of nonnegative orthants and PSD cones. A constraint
:math:`M(x) \preceq 0` becomes :math:`s = \operatorname{svec}(-M(x)) \in
\mathcal S_+`, i.e. :math:`b = -\operatorname{svec}(M_0)`,
:math:`A_{:,k} = \operatorname{svec}(M_k)`; ``svec`` stacks the upper triangle column by
column with off-diagonal entries scaled by :math:`\sqrt 2` (Clarabel's
``PSDTriangleConeT`` convention, so that :math:`\operatorname{svec}(X)^T
\operatorname{svec}(Y) = \operatorname{tr}(XY)`). A symmetric matrix variable :math:`P`
is its own ``svec`` coordinates, so :math:`P \succeq 0` is the cone membership of those
coordinates.

Why not cvxpy: for these problems cvxpy's compile took as long as Clarabel's solve, and
importing it costs 0.7 s per command (``benchmarks/analysis.py``). The other solvers
(SDPA, SCS) still go through cvxpy, built by :func:`to_cvxpy` from the same
:class:`ConicProblem`, so every solver sees the same numbers.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike

from ..model.system import Matrix

__all__ = ["Affine", "affine_bmat", "svec_index", "sym_variable", "scalar_variable", "matrix_variable",
           "local_variables", "KeyedVariables", "evaluate", "unit_rows", "Columns", "Rows", "ConicProblem", "solve_clarabel", "solve_clarabel_dual", "to_cvxpy"]

_R2 = math.sqrt(2.0)


class Affine:
    """A matrix (or scalar) whose entries are affine in ``K`` variables.

    ``const`` has the matrix's shape; ``lin`` has one more axis of length ``K``. Supports
    what the LMI blocks use: ``+``, ``-``, ``@`` with constant matrices, products with
    (and division by) numbers (and a scalar :class:`Affine` times a constant matrix), ``.T``.
    """

    __array_ufunc__ = None  # numpy defers ``ndarray @ Affine`` to __rmatmul__

    def __init__(self, const: Matrix, lin: Matrix) -> None:
        self.const = np.asarray(const, dtype=float)
        self.lin = np.asarray(lin, dtype=float)

    @property
    def shape(self) -> tuple[int, ...]:
        """Shape of the matrix (``()`` for a scalar)."""
        return self.const.shape

    @property
    def T(self) -> Affine:
        """Transpose."""
        return Affine(self.const.T, np.swapaxes(self.lin, 0, 1))

    def __add__(self, other: Any) -> Affine:
        if isinstance(other, Affine):
            return Affine(self.const + other.const, self.lin + other.lin)
        return Affine(self.const + np.asarray(other, dtype=float), self.lin)

    __radd__ = __add__

    def __neg__(self) -> Affine:
        return Affine(-self.const, -self.lin)

    def __sub__(self, other: Any) -> Affine:
        return self + (-other)

    def __rsub__(self, other: Any) -> Affine:
        return (-self) + other

    def __mul__(self, other: Any) -> Affine:
        value = np.asarray(other, dtype=float)
        if value.ndim == 0:
            return Affine(self.const * value, self.lin * value)
        if self.const.ndim != 0:
            raise TypeError("only a scalar Affine can multiply a matrix")
        return Affine(self.const * value, value[..., None] * self.lin)

    __rmul__ = __mul__

    def __truediv__(self, other: float) -> Affine:
        return Affine(self.const / float(other), self.lin / float(other))

    def __matmul__(self, other: Matrix) -> Affine:
        M = np.asarray(other, dtype=float)
        return Affine(self.const @ M, np.einsum("ijk,jl->ilk", self.lin, M))

    def __rmatmul__(self, other: Matrix) -> Affine:
        M = np.asarray(other, dtype=float)
        return Affine(M @ self.const, np.einsum("ij,jlk->ilk", M, self.lin))


def affine_bmat(rows: Sequence[Sequence[Any]]) -> Affine:
    """:func:`numpy.block` for rows mixing :class:`Affine` and constant matrices."""
    K = next(e.lin.shape[-1] for row in rows for e in row if isinstance(e, Affine))

    def parts(e: Any) -> tuple[Matrix, Matrix]:
        if isinstance(e, Affine):
            return e.const, e.lin
        c = np.asarray(e, dtype=float)
        return c, np.zeros(c.shape + (K,))

    split = [[parts(e) for e in row] for row in rows]
    const = np.block([[c for c, _ in row] for row in split])
    lin = np.concatenate([np.concatenate([m for _, m in row], axis=1) for row in split], axis=0)
    return Affine(const, lin)


def svec_index(d: int) -> tuple[np.ndarray, np.ndarray, Matrix]:
    """``(rows, cols, weights)`` of ``svec`` for a ``d x d`` matrix (module docstring)."""
    cols, rows = np.tril_indices(d)  # row-major lower triangle = column-major upper
    return rows, cols, np.where(rows == cols, 1.0, _R2)


def sym_variable(n: int, first: int, K: int) -> Affine:
    """The symmetric ``n x n`` matrix whose ``svec`` coordinates are variables
    ``first, ..., first + n (n + 1) / 2 - 1`` of ``K``."""
    r, c, w = svec_index(n)
    lin = np.zeros((n, n, K))
    k = first + np.arange(len(r))
    lin[r, c, k] = 1.0 / w
    lin[c, r, k] = 1.0 / w
    return Affine(np.zeros((n, n)), lin)


def scalar_variable(index: int, K: int) -> Affine:
    """Variable ``index`` of ``K`` as a scalar :class:`Affine`."""
    lin = np.zeros(K)
    lin[index] = 1.0
    return Affine(np.zeros(()), lin)


def matrix_variable(rows: int, cols: int, first: int, K: int) -> Affine:
    """The general ``rows x cols`` matrix whose entries, row by row, are variables
    ``first, ..., first + rows * cols - 1`` of ``K``."""
    lin = np.zeros((rows, cols, K))
    r, c = np.divmod(np.arange(rows * cols), cols)
    lin[r, c, first + np.arange(rows * cols)] = 1.0
    return Affine(np.zeros((rows, cols)), lin)


def local_variables(pieces: Sequence[tuple[str, int, tuple[int, ...]]]) -> tuple[list[Affine], Matrix]:
    """The variables one constraint uses, on columns of their own: ``pieces`` lists
    ``(kind, first global column, shape)`` with ``kind`` ``"sym"`` (shape ``(n,)``: a
    symmetric matrix in ``svec`` coordinates, :func:`sym_variable`), ``"mat"`` (shape
    ``(rows, cols)``, :func:`matrix_variable`) or ``"scalar"`` (shape ``()``). Returns the
    :class:`Affine` of each piece over the local columns and the global column of each
    local one (the ``columns`` of :meth:`Rows.lmi`). Building a block on its own few
    columns keeps the ``lin`` arrays small when the program has many variables."""
    sizes = [shape[0] * (shape[0] + 1) // 2 if kind == "sym" else int(np.prod(shape)) for kind, _, shape in pieces]
    K = sum(sizes)
    out: list[Affine] = []
    pos = 0
    for (kind, _, shape), size in zip(pieces, sizes):
        if kind == "sym":
            out.append(sym_variable(shape[0], pos, K))
        elif kind == "mat":
            out.append(matrix_variable(shape[0], shape[1], pos, K))
        else:
            out.append(scalar_variable(pos, K))
        pos += size
    columns = np.concatenate([np.arange(first, first + size) for (_, first, _), size in zip(pieces, sizes)])
    return out, columns.astype(int)


class KeyedVariables:
    """The variables one constraint uses, on columns of their own, by key: for each key of
    ``keys`` (once, in their order) the symmetric ``d x d`` matrix ``var[key]`` whose
    ``svec`` starts at the program's column ``first(*key)``, then the program's columns
    ``extra``; ``columns`` maps the constraint's columns to the program's (as
    :func:`local_variables`), ``K`` counts them. The clock-dependent certificates of the
    sampled loop (``analysis.moments.sampled_gamma``, ``analysis.moments.sampled_quadratic``)
    key their storage matrices by piece and joint state."""

    def __init__(self, d: int, first: Callable[..., int], keys: Sequence[tuple[int, ...]], extra: Sequence[int]) -> None:
        pp = d * (d + 1) // 2
        self.keys = list(dict.fromkeys(keys))
        cols = [np.arange(first(*key), first(*key) + pp) for key in self.keys] + [np.asarray(extra, dtype=int)]
        self.columns = np.concatenate(cols).astype(int)
        self.K = len(self.columns)
        self.var = {key: sym_variable(d, pos * pp, self.K) for pos, key in enumerate(self.keys)}
        self.base = len(self.keys) * pp

    def scalar(self, k: int) -> Affine:
        """Extra column ``k`` as a scalar :class:`Affine`."""
        return scalar_variable(self.base + k, self.K)

    def sym(self, first: int, m: int) -> Affine:
        """The symmetric ``m x m`` matrix whose ``svec`` is extra columns ``first, first + 1, ...``."""
        return sym_variable(m, self.base + first, self.K)


def evaluate(M: Affine, x: Matrix) -> Matrix:
    """The value :math:`M_0 + \\sum_k x_k M_k` of ``M`` at the point ``x``."""
    return M.const + M.lin @ np.asarray(x, dtype=float)


def unit_rows(K: int, columns: Sequence[int] | np.ndarray, value: float = -1.0) -> sp.csr_matrix:
    """The rows ``value * e_k^T``, one per ``k`` in ``columns``, of a program of ``K``
    columns, as a sparse matrix (for :meth:`Rows.nonneg`: ``value = -1`` makes
    ``x_k >= 0``); rows of a dense ``numpy.eye(K)`` cost ``K**2`` memory."""
    idx = np.asarray(columns, dtype=int).ravel()
    return sp.csr_matrix((np.full(idx.size, float(value)), (np.arange(idx.size), idx)), shape=(idx.size, K))


class Columns:
    """Named runs of program columns, allocated in order: :meth:`add` ``count``
    variables of ``size`` columns each under ``name``; :meth:`at` the first column of
    the ``k``-th; ``K`` the columns so far."""

    def __init__(self) -> None:
        self.K = 0
        self.runs: dict[str, tuple[int, int]] = {}

    def add(self, name: str, count: int, size: int) -> None:
        """Allocate ``count`` variables of ``size`` columns under ``name``."""
        self.runs[name] = (self.K, size)
        self.K += count * size

    def at(self, name: str, k: int = 0) -> int:
        """First column of variable ``k`` of ``name``."""
        first, size = self.runs[name]
        return first + k * size


class Rows:
    """Builder of the constraint rows ``A x + s = b`` cone by cone."""

    def __init__(self, K: int) -> None:
        self.K = K
        self.blocks: list[tuple[str, int, sp.csr_matrix, Matrix]] = []

    def nonneg(self, A: Matrix | sp.spmatrix, b: ArrayLike) -> None:
        """``b - A x >= 0`` elementwise; ``A`` dense or a scipy.sparse matrix (e.g.
        :func:`unit_rows`)."""
        if sp.issparse(A):
            A_rows = sp.csr_matrix(A, dtype=float)
        else:
            A_rows = sp.csr_matrix(np.atleast_2d(np.asarray(A, dtype=float)))
        self.blocks.append(("nonneg", A_rows.shape[0], A_rows, np.asarray(b, dtype=float).ravel()))

    def lmi(self, M: Affine, columns: Matrix) -> None:
        """``M(x) <= 0`` in the semidefinite order (``M`` symmetrised first); variable
        ``k`` of ``M`` is column ``columns[k]`` of the program."""
        const = 0.5 * (M.const + M.const.T)
        lin = 0.5 * (M.lin + np.swapaxes(M.lin, 0, 1))
        r, c, w = svec_index(const.shape[0])
        local = sp.coo_matrix(lin[r, c, :] * w[:, None])
        A = sp.csr_matrix((local.data, (local.row, np.asarray(columns)[local.col])), shape=(len(r), self.K))
        self.blocks.append(("psd", const.shape[0], A, -const[r, c] * w))

    def used(self) -> np.ndarray:
        """Which columns some row added so far involves (a variable no constraint
        involves is left out of a program, as cvxpy leaves it out: :meth:`ConicProblem.restrict`)."""
        out = np.zeros(self.K, dtype=bool)
        for block in self.blocks:
            out[block[2].indices] = True
        return out

    def extended(self, A: Matrix | sp.spmatrix, b: ArrayLike) -> Rows:
        """A copy with the rows ``b - A x >= 0`` added."""
        out = Rows(self.K)
        out.blocks = list(self.blocks)
        out.nonneg(A, b)
        return out

    def problem(self, c: Matrix) -> ConicProblem:
        """The program ``min c x`` subject to every row added (nonnegative rows first)."""
        ordered = sorted(self.blocks, key=lambda blk: blk[0] != "nonneg")
        A = sp.vstack([blk[2] for blk in ordered], format="csc")
        b = np.concatenate([blk[3] for blk in ordered])
        cones = tuple((kind, dim) for kind, dim, _, _ in ordered)
        return ConicProblem(np.asarray(c, dtype=float), A, b, cones)


@dataclass(frozen=True, eq=False)
class ConicProblem:
    """``min c x`` s.t. ``A x + s = b``, ``s`` in the product of ``cones``
    (``("nonneg", k)`` or ``("psd", d)``, in row order)."""

    c: Matrix
    A: sp.csc_matrix
    b: Matrix
    cones: tuple[tuple[str, int], ...]

    def fix(self, index: int, value: float) -> ConicProblem:
        """The same program with variable ``index`` fixed at ``value`` (column removed)."""
        keep = np.arange(self.A.shape[1]) != index
        b = self.b - value * self.A[:, index].toarray().ravel()
        return ConicProblem(self.c[keep], self.A[:, keep].tocsc(), b, self.cones)

    def restrict(self, keep: np.ndarray) -> ConicProblem:
        """The program in the columns where ``keep`` (a boolean mask) holds, the others
        fixed at zero."""
        return ConicProblem(self.c[keep], self.A[:, keep].tocsc(), self.b, self.cones)

    def slack(self, x: Matrix) -> Matrix:
        """``b - A x`` (for tests and diagnostics)."""
        return self.b - self.A @ x


#: Clarabel status -> the status names used throughout (cvxpy's).
_CLARABEL_STATUS = {
    "Solved": "optimal",
    "AlmostSolved": "optimal_inaccurate",
    "PrimalInfeasible": "infeasible",
    "AlmostPrimalInfeasible": "infeasible_inaccurate",
    "DualInfeasible": "unbounded",
    "AlmostDualInfeasible": "unbounded_inaccurate",
    "MaxIterations": "user_limit",
    "MaxTime": "user_limit",
}


def solve_clarabel(problem: ConicProblem, settings: dict[str, Any]) -> tuple[str, str, Matrix | None]:
    """Solve with Clarabel; ``(status, message, x)``, ``x`` ``None`` without a point.

    Statuses outside ``_CLARABEL_STATUS`` (numerical error, insufficient progress)
    become ``"error"`` with Clarabel's status in the message.
    """
    status, message, x, _ = solve_clarabel_dual(problem, settings)
    return status, message, x


def solve_clarabel_dual(problem: ConicProblem, settings: dict[str, Any]) -> tuple[str, str, Matrix | None, Matrix | None]:
    """:func:`solve_clarabel` that also returns the dual point ``z`` (``A' z + c = 0``,
    ``z`` in the dual cone; ``-b' z`` is the dual objective, a lower bound on
    ``min c' x`` up to the solver's tolerances), ``None`` with ``x``."""
    import clarabel

    opts = clarabel.DefaultSettings()
    opts.verbose = False
    for key, value in settings.items():
        setattr(opts, key, value)
    cones = [clarabel.NonnegativeConeT(d) if kind == "nonneg" else clarabel.PSDTriangleConeT(d)
             for kind, d in problem.cones]
    K = problem.A.shape[1]
    solver = clarabel.DefaultSolver(sp.csc_matrix((K, K)), problem.c, problem.A, problem.b, cones, opts)
    sol = solver.solve()
    raw = str(sol.status)
    status = _CLARABEL_STATUS.get(raw, "error")
    message = "" if raw in _CLARABEL_STATUS else f"clarabel status {raw}"
    if status not in ("optimal", "optimal_inaccurate"):
        return status, message, None, None
    return status, message, np.asarray(sol.x, dtype=float), np.asarray(sol.z, dtype=float)


def to_cvxpy(problem: ConicProblem) -> tuple[Any, Any]:
    """The same program as a cvxpy problem (for the solvers without a native path);
    returns ``(cvxpy.Problem, x)``."""
    import cvxpy as cp

    K = problem.A.shape[1]
    x = cp.Variable(K)
    slack = problem.b - problem.A @ x
    cons = []
    start = 0
    for kind, d in problem.cones:
        if kind == "nonneg":
            cons.append(slack[start:start + d] >= 0)
            start += d
            continue
        r, c, w = svec_index(d)
        size = len(r)
        # smat: entry (r, c) and (c, r) of vec(S) (column-major) get svec_k / w_k
        rows = np.concatenate([c * d + r, r * d + c])
        cols = np.concatenate([np.arange(size)] * 2)
        vals = np.concatenate([1.0 / w] * 2)
        diag = r == c
        vals[size:][diag] = 0.0  # diagonal counted once
        T = sp.csr_matrix((vals, (rows, cols)), shape=(d * d, size))
        S = cp.reshape(T @ slack[start:start + size], (d, d), order="F")
        cons.append(0.5 * (S + S.T) >> 0)
        start += size
    return cp.Problem(cp.Minimize(problem.c @ x), cons), x
