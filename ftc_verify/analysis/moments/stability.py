r"""Exact mean-square stability: the spectral abscissa of the second-moment generator.

With :math:`X_s(t) = E[\xi \xi^T 1\{\theta_t = s\}]` and :math:`w = 0`, Dynkin's formula
gives the linear ODE (derived here, not in the paper)

.. math::

    \dot X_s = A_s X_s + X_s A_s^T + \sum_{s'} Q_{s' s} X_{s'} ,

so in half-vectorised (``vech``) Kronecker form :math:`\dot v = \mathcal{L} v` with

.. math::

    \mathcal{L} = \operatorname{blockdiag}_s\bigl(L_n (I \otimes A_s + A_s \otimes I) D_n\bigr)
                  + Q^T \otimes I_{n(n+1)/2},

:math:`D_n` the duplication and :math:`L_n` the elimination matrix. The nominal loop is
mean-square (equivalently mean-exponentially, paper Remark 1) stable iff the spectral
abscissa :math:`\max \operatorname{Re} \lambda(\mathcal{L}) < 0`. Restricting to
symmetric matrices loses nothing: the operator is resolvent-positive, so its abscissa
is attained at a positive semidefinite eigenvector.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import scipy.linalg

from ..closedloop import ClosedLoop
from ..conditioning import Similarity, conditioning_transform
from ..box import BOX_BUDGET_SECONDS, SUSPECT_MARGIN, RegionVerdict, box_stability
from ...model.system import Matrix
from .vech import dense_solve, duplication_matrix, lyapunov_vech, second_moment_matrix, unvech_stack, vech_order

__all__ = [
    "MSSResult",
    "duplication_matrix",
    "second_moment_generator",
    "second_moment_matrix",
    "unvech_stack",
    "lyapunov_stack_solution",
    "vech_order",
    "dense_solve",
    "SHIFT_DENSE_ROWS",
    "sparse_mode_blocks",
    "spectral_abscissa",
    "generator_size",
    "DENSE_LIMIT",
    "mean_square_stability",
    "abscissa_below",
    "abscissa_near",
    "SHIFT_TEST_MIN",
    "SHIFT_TEST_LIMIT",
    "SHIFT_GMRES_RTOL",
    "SHIFT_GMRES_RESTARTS",
    "NEAR_ROUND_SHRINK",
    "communicating_classes",
    "CLASS_SPLIT_ROWS",
]


#: Largest generator (rows) handled by dense eigenvalues; larger ones go matrix-free
#: (a dense N x N eigenproblem at N = 1500 takes about a second here, and the dense
#: construction needs n^2 x n^2 Kronecker products per mode).
DENSE_LIMIT = 1500


def second_moment_generator(loop: ClosedLoop, beta: Matrix) -> Matrix:
    """The matrix :math:`\\mathcal{L}` of the module docstring for the rate array ``beta``
    (shape :attr:`JointChain.rate_shape`)."""
    return second_moment_matrix(loop.A, loop.chain.generator(beta))


def lyapunov_stack_solution(A: Sequence[Matrix], Q: Matrix, R: Sequence[Matrix] | None = None) -> np.ndarray | None:
    r"""The float stack :math:`X` with :math:`A_s X_s + X_s A_s^T + \sum_t Q_{ts} X_t = -R_s`
    for every joint state (:math:`\mathcal L(X) = -R` of the module docstring; ``R = I``
    by default), as symmetric matrices: dense up to :data:`DENSE_LIMIT` rows, sparse LU
    above. The adjoint :math:`\mathcal L^*(P) = -R` is this with every :math:`A_s` and
    :math:`Q` transposed. ``None`` when the solve fails or is not finite."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    n, modes = A[0].shape[0], len(A)
    rows, cols = vech_order(n)
    if R is None:
        rhs = np.tile(-(rows == cols).astype(float), modes)
    else:
        rhs = -np.concatenate([np.asarray(r)[rows, cols] for r in R])
    try:
        if modes * len(rows) > DENSE_LIMIT:
            G = sp.block_diag([sp.csr_matrix(lyapunov_vech(a)) for a in A]) + sp.kron(
                np.asarray(Q).T, sp.identity(len(rows)))
            v = splu(G.tocsc()).solve(rhs)
        else:
            v = dense_solve(second_moment_matrix(A, Q), rhs)  # no condition warning: callers judge it
    except (RuntimeError, ValueError, np.linalg.LinAlgError, scipy.linalg.LinAlgError):
        return None
    if not np.all(np.isfinite(v)):
        return None
    return unvech_stack(v, modes, n)


def spectral_abscissa(loop: ClosedLoop, beta: Matrix) -> float:
    """Largest real part of the eigenvalues of the second-moment generator at ``beta``.

    Dense eigenvalues up to :data:`DENSE_LIMIT` rows (from :data:`CLASS_SPLIT_ROWS` rows
    those of the diagonal block of each communicating class of the joint chain at
    ``beta``: the same spectrum, :func:`communicating_classes`); above, the checked
    matrix-free test of :mod:`ftc_verify.analysis.moments.matrix_free` (whose sign is
    proved by a Lyapunov certificate; its value is ARPACK's).

    A shift-invert Arnoldi variant (shift at a Collatz-Wielandt bound) was tried and
    removed: with a large shift every ``1/(sigma - mu)`` agrees to about 1e-9, and it
    returned a complex pair at -1.15 instead of the real abscissa -1.04 (n=12, m=4,
    ``benchmarks/synthesis.py``) -- wrong in the unsafe direction.
    """
    if generator_size(loop) > DENSE_LIMIT:
        from .matrix_free import matrix_free_abscissa

        return matrix_free_abscissa(loop, beta)
    Q = loop.chain.generator(beta)
    classes = communicating_classes(Q) if generator_size(loop) >= CLASS_SPLIT_ROWS else [np.arange(len(loop.A))]
    return max(float(np.max(scipy.linalg.eigvals(second_moment_matrix([loop.A[s] for s in c], Q[np.ix_(c, c)]),
                                                 check_finite=False).real)) for c in classes)


#: Generators (rows) from which :func:`spectral_abscissa` takes the eigenvalues class by
#: class (:func:`communicating_classes`); below, the whole matrix's cost less than finding
#: the classes (paper example, 40 rows: 0.12 ms per vertex whole, 0.33 ms by classes).
CLASS_SPLIT_ROWS = 100


def communicating_classes(Q: Matrix) -> list[np.ndarray]:
    r"""The joint states of the generator ``Q`` grouped into its communicating classes
    (the strongly connected components of the graph of its nonzero off-diagonal rates),
    each class's states ascending (the classes in scipy's order).

    :math:`\mathcal L` couples :math:`X_s` to :math:`X_t` only through :math:`q_{ts}`
    (module docstring), so with the joint states ordered class by class (a class before those it
    reaches) it is block triangular, and its eigenvalues are those of its diagonal blocks together: the block of
    a class :math:`C` is ``second_moment_matrix(A[C], Q[C, C])`` (the rates leaving
    :math:`C` stay on the diagonal). One class (an irreducible chain) is the whole
    generator. The three-tank observer loop at a rate vertex: a class of 10 joint states
    and 6 unreachable ones, eigenvalues of 210 + 6 x 21 rows instead of 336 (a quarter of
    the flops).
    """
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    graph = np.asarray(Q, dtype=float) != 0.0
    np.fill_diagonal(graph, False)
    count, labels = connected_components(sp.csr_matrix(graph), directed=True, connection="strong")
    if count == 1:
        return [np.arange(len(labels))]
    return [np.flatnonzero(labels == k) for k in range(count)]


def generator_size(loop: ClosedLoop) -> int:
    """Rows of the second-moment generator: joint modes times ``n (n + 1) / 2``."""
    return len(loop.A) * loop.n * (loop.n + 1) // 2


#: Generators (rows) given the shift test before eigenvalues (sparse LU up to
#: :data:`DENSE_LIMIT` rows, GMRES above); outside this range every vertex is evaluated by
#: :func:`spectral_abscissa` (below, dense eigenvalues cost less than the test).
SHIFT_TEST_MIN, SHIFT_TEST_LIMIT = 100, 20_000
#: Generators (rows) up to which the shift test factors the dense matrix (LAPACK ``gesv``:
#: 1 ms at 324 rows, against 3-5 ms for SuperLU and its sparse assembly), sparse above.
SHIFT_DENSE_ROWS = 600
#: GMRES's relative residual in the shift test above :data:`DENSE_LIMIT` rows: the test
#: recomputes the residual from :math:`X` and needs it only within a fraction of
#: :math:`I`, so a loose solve decides the same (and converges far sooner near :math:`\mu`).
SHIFT_GMRES_RTOL = 1e-6
#: :func:`abscissa_near` gives up (``None``) after a round of six power steps that did not
#: shrink its bracket below this fraction of its width after the round's first step.
NEAR_ROUND_SHRINK = 0.5
#: GMRES restarts (of 60 steps) of that test: near :math:`\mu` it converges slowly, and
#: a vertex not shown below is evaluated by :func:`spectral_abscissa` instead.
SHIFT_GMRES_RESTARTS = 2


def sparse_mode_blocks(loop: ClosedLoop) -> Any:
    """The ``beta``-independent part of :func:`second_moment_generator` (the
    block-diagonal Kronecker sums), sparse."""
    import scipy.sparse as sp

    D, L = duplication_matrix(loop.n)
    eye = np.eye(loop.n)
    return sp.block_diag([sp.csr_matrix(L @ (np.kron(eye, A) + np.kron(A, eye)) @ D) for A in loop.A], format="csc")


def abscissa_below(loop: ClosedLoop, beta: Matrix, sigma: float, *, modes_part: Any = None,
                   norms: Sequence[float] | None = None) -> bool:
    r"""Certified test: ``True`` only if the spectral abscissa at ``beta`` is ``< sigma``.

    Solves :math:`\mathcal L(X) - \sigma X = -I` (every joint mode; sparse LU up to
    :data:`DENSE_LIMIT` rows, above it
    :func:`~ftc_verify.analysis.bounded_real.coupled_lyapunov` on :math:`A_s - \sigma I/2`:
    GMRES preconditioned by one Schur form per joint state, no fill-in, at most
    :data:`SHIFT_GMRES_RESTARTS` restarts; how :math:`X` was found does not matter) and
    checks by Cholesky that :math:`X_s \succ 0` and that the residual
    :math:`-(A_s X_s + X_s A_s^T + \sum_{s'} Q_{s's} X_{s'} - \sigma X_s)`, recomputed
    from :math:`X` with matrix products, is positive definite beyond a rounding margin.
    That proves :math:`\mu < \sigma` for the resolvent-positive
    :math:`\mathcal L` (derived here): the adjoint has an eigenvector :math:`Z \succeq 0`,
    :math:`Z \ne 0`, with :math:`\mathcal L^*(Z) = \mu Z` (Krein-Rutman), so
    :math:`0 > \langle \mathcal L(X) - \sigma X, Z\rangle = (\mu - \sigma)\langle X, Z\rangle`
    with :math:`\langle X, Z\rangle > 0`. ``False`` means "not shown", not "above".
    Up to :data:`SHIFT_DENSE_ROWS` rows the LU is LAPACK's dense one (how :math:`X` was
    found does not matter); ``norms``: the spectral norms of ``loop.A``, or upper bounds
    of them (computed here when ``None``; the same at every vertex). They enter the
    rounding bound of the proof: numbers below the true norms would make it unsound.
    """
    n, modes = loop.n, len(loop.A)
    if norms is not None and len(norms) != modes:
        raise ValueError(f"abscissa_below: {len(norms)} norms for {modes} joint-state matrices")
    Q = loop.chain.generator(beta)
    if generator_size(loop) > DENSE_LIMIT:
        from ..bounded_real import coupled_lyapunov

        shifted = [(a - 0.5 * sigma * np.eye(n)).T for a in loop.A]
        found = coupled_lyapunov(shifted, Q.T, [np.eye(n)] * modes, rtol=SHIFT_GMRES_RTOL,
                                 maxiter=SHIFT_GMRES_RESTARTS)
        if found is None:
            return False
        X = np.array(found)
    elif generator_size(loop) <= SHIFT_DENSE_ROWS:
        G = second_moment_matrix(loop.A, Q)
        G[np.diag_indices_from(G)] -= sigma
        rows, cols = vech_order(n)
        try:
            v = dense_solve(G, np.tile(-(rows == cols).astype(float), modes))
        except np.linalg.LinAlgError:  # exactly singular
            return False
        if not np.all(np.isfinite(v)):
            return False
        X = unvech_stack(v, modes, n)
    else:
        import scipy.sparse as sp
        from scipy.sparse.linalg import splu

        base = sparse_mode_blocks(loop) if modes_part is None else modes_part
        G = base + sp.kron(Q.T, sp.identity(n * (n + 1) // 2), format="csc")
        rows, cols = vech_order(n)
        rhs = np.tile(-(rows == cols).astype(float), modes)
        try:
            v = splu((G - sigma * sp.identity(G.shape[0], format="csc")).tocsc()).solve(rhs)
        except RuntimeError:  # exactly singular
            return False
        if not np.all(np.isfinite(v)):
            return False
        X = unvech_stack(v, modes, n)
    coupled = np.einsum("ts,tij->sij", Q, X)
    x_norm = 64 * n * np.finfo(float).eps * np.linalg.norm(X, 2, axis=(1, 2)).max()
    a_norms = [np.linalg.norm(A, 2) for A in loop.A] if norms is None else norms
    for s, A in enumerate(loop.A):
        Y = A @ X[s] + X[s] @ A.T + coupled[s] - sigma * X[s]
        bound = x_norm * (2 * a_norms[s] + abs(sigma) + np.abs(Q).sum())  # rounding in Y
        try:
            np.linalg.cholesky(X[s])
            np.linalg.cholesky(-Y - bound * np.eye(n))
        except np.linalg.LinAlgError:
            return False
    return True


def abscissa_near(loop: ClosedLoop, beta: Matrix, level: float, *, modes_part: Any = None,
                  rtol: float = 1e-12, max_steps: int = 80, norms: Sequence[float] | None = None) -> float | None:
    r"""The spectral abscissa :math:`\mu` at ``beta`` when it is known to lie near
    ``level`` (a vertex close to one already evaluated), without dense eigenvalues.

    First a shift :math:`\sigma > \mu` is proved by :func:`abscissa_below` (at
    ``level`` plus 1 %, 4 %, ... of ``1 + |level|``). Then :math:`T = (\sigma - \mathcal
    L)^{-1}` maps positive semidefinite matrices to positive semidefinite ones (it is
    :math:`\int_0^\infty e^{-\sigma t} e^{\mathcal L t}\,dt`) and its spectral radius
    is :math:`1/(\sigma - \mu)`, since :math:`|\sigma - \lambda| \ge \sigma - \mu` for
    every eigenvalue :math:`\lambda` of :math:`\mathcal L`. Power iteration
    :math:`X \leftarrow T(X)` from :math:`X = I` gives Collatz-Wielandt bounds at every
    step: with :math:`Y = T(X)`, :math:`X \succ 0`,

    .. math::

        \min_s \lambda_{min}(Y_s, X_s) \le \rho(T) \le \max_s \lambda_{max}(Y_s, X_s),

    (generalised eigenvalues), hence a bracket on :math:`\mu`. Every six steps the shift
    moves to the bracket's top plus its width (still above :math:`\mu`), so the
    iteration converges fast. Returns the bracket's midpoint once its width is at most
    ``rtol * max(1, |mu|)``; ``None`` when no shift is proved or the iteration stalls
    (the caller then uses dense eigenvalues). ``norms``: as in :func:`abscissa_below`.

    Stalls are recognised after one round of six steps: the round ends with ``None``
    unless it at least halved the bracket (:data:`NEAR_ROUND_SHRINK`). Where the
    eigenvector of :math:`\mu` is positive definite the round shrinks the bracket by
    1e3-1e8 (the loops of the tests); where it is singular -- a reducible chain whose
    transient joint states carry none of it, as a permanent fault makes the nominal
    state -- the lower Collatz-Wielandt bound stays at the second eigenvalue of the
    transient states and the bracket never closes (the three-tank observer loop: width
    0.1235 after 6 steps, 0.1233 after 84, cond :math:`X_s` 1e14). The bracket is a
    stopping rule, not a proof: this only returns sooner what the 80 steps returned.
    """
    import scipy.linalg
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    n, modes = loop.n, len(loop.A)
    base = sparse_mode_blocks(loop) if modes_part is None else modes_part
    G = base + sp.kron(loop.chain.generator(beta).T, sp.identity(n * (n + 1) // 2), format="csc")
    eye = sp.identity(G.shape[0], format="csc")
    sigma = next((level + d * (1 + abs(level)) for d in (0.01, 0.04, 0.16, 0.64)
                  if abscissa_below(loop, beta, level + d * (1 + abs(level)), modes_part=base, norms=norms)), None)
    if sigma is None:
        return None
    rows, cols = vech_order(n)
    X = np.tile(np.eye(n), (modes, 1, 1))
    lower, upper = -np.inf, sigma
    steps = 0
    while steps < max_steps:
        try:
            lu = splu((sigma * eye - G).tocsc())
        except RuntimeError:
            return None
        first = np.inf  # the bracket's width after the round's first step
        for _ in range(6):
            steps += 1
            Y = unvech_stack(lu.solve(X[:, rows, cols].ravel()), modes, n)
            try:
                ev = [scipy.linalg.eigh(Y[s], X[s], eigvals_only=True) for s in range(modes)]
            except (np.linalg.LinAlgError, ValueError):
                return None
            lo, hi = min(e[0] for e in ev), max(e[-1] for e in ev)
            if not (np.isfinite(hi) and lo > 0):
                return None
            lower, upper = max(lower, sigma - 1.0 / lo), min(upper, sigma - 1.0 / hi)
            if upper - lower <= rtol * max(1.0, abs(upper)):
                return 0.5 * (lower + upper)
            first = upper - lower if first == np.inf else first
            X = Y / np.abs(Y).max()
        if upper - lower > NEAR_ROUND_SHRINK * first:  # stalled (docstring): dense eigenvalues instead
            return None
        sigma = upper + max(upper - lower, rtol * max(1.0, abs(upper)))
    return None


@dataclass(frozen=True, eq=False)
class MSSResult:
    """The verified verdict over the whole rate box and the float estimate of the worst
    constant-rate spectral abscissa.

    ``verdict`` is "stable", "not stable" or "undecided" over *every* rate vector of the
    box (:mod:`ftc_verify.analysis.box`); ``vertex_verdicts`` names what was proved over
    which region (:class:`~ftc_verify.analysis.box.RegionVerdict`: the proved sub-boxes,
    the witness of instability, or, last, the sub-box where the proof gave up);
    ``time_varying`` says that one Lyapunov stack covers the whole box, so the verdict
    "stable" holds for rates that vary in time inside it too.

    ``spectral_abscissa`` is a float64 estimate (coordinates of
    :func:`~ftc_verify.analysis.conditioning.conditioning_transform`): the largest
    abscissa found over the rate vertices evaluated and the point where instability was
    proved, found at ``worst_beta`` (a rate array, :attr:`JointChain.rate_shape`).
    ``exhaustive`` tells whether every vertex was evaluated (otherwise a greedy vertex
    ascent was used). It is an estimate, not a bound: the verdict is the proof.
    """

    spectral_abscissa: float
    worst_beta: Matrix
    vertices_evaluated: int
    exhaustive: bool
    exact_evaluations: int = 0
    verdict: str = "undecided"
    vertex_verdicts: tuple[RegionVerdict, ...] = ()
    conditioning: Similarity | None = None
    time_varying: bool = False
    boxes: int = 0
    reason: str = ""

    @property
    def stable(self) -> bool:
        """Proved mean-square stable for every constant rate vector of the box."""
        return self.verdict == "stable"

    @property
    def unstable(self) -> bool:
        """Proved not mean-square stable at some rate vector of the box."""
        return self.verdict == "not stable"

    @property
    def undecided(self) -> bool:
        """Neither proved (the branch and bound ran out of budget or precision)."""
        return self.verdict == "undecided"

    @property
    def spectral_abscissa_contradicted(self) -> bool:
        """The float estimate ``spectral_abscissa`` has the sign the proved verdict rules out
        (float64 cannot resolve the realisation; the verdict is the proof)."""
        return (self.stable and self.spectral_abscissa >= 0.0) or (self.unstable and self.spectral_abscissa < 0.0)

    @property
    def witness(self) -> RegionVerdict | None:
        """The rate vector where instability was proved (``None`` unless "not stable")."""
        return self.vertex_verdicts[-1] if self.unstable and self.vertex_verdicts else None

    def proved_by(self, certificate: str, chain: Any) -> MSSResult:
        """This result, "undecided" by the branch and bound, decided "stable" by another
        proof over the whole box (a certified Theorem 3.1 LMI: one Lyapunov stack for
        every rate of the box, time-varying included)."""
        region = RegionVerdict(chain.rate_min.copy(), chain.rate_max.copy(), "stable", certificate, 128, 0.0)
        return replace(self, verdict="stable", vertex_verdicts=(region,), time_varying=True,
                       reason=f"the branch and bound was undecided ({self.reason}); {certificate}")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary."""
        witness = self.witness
        return {
            "spectral_abscissa": self.spectral_abscissa,
            "spectral_abscissa_contradicted": self.spectral_abscissa_contradicted,
            "stable": self.stable,
            "verdict": self.verdict,
            "verified_by": describe_regions(self.verdict, self.vertex_verdicts, self.time_varying, self.boxes),
            "time_varying": self.time_varying,
            "sub_boxes": self.boxes,
            "reason": self.reason,
            "witness": None if witness is None else {
                "rates": witness.rate_min.tolist(), "float_abscissa": witness.estimate,
                "abscissa_enclosure": None if witness.enclosure is None else list(witness.enclosure)},
            "vertex_verdicts": [v.to_dict() for v in self.vertex_verdicts],
            "conditioning": None if self.conditioning is None else self.conditioning.to_dict(),
            "worst_beta": self.worst_beta.tolist(),
            "vertices_evaluated": self.vertices_evaluated,
            "exhaustive": self.exhaustive,
            "exact_evaluations": self.exact_evaluations,
        }


def describe_regions(verdict: str, regions: Sequence[RegionVerdict], time_varying: bool, boxes: int) -> str:
    """One line: what the verdict rests on."""
    if verdict == "stable":
        if time_varying:
            return (f"the whole rate box with one Lyapunov stack ({regions[0].method}); "
                    "holds for time-varying rates too")
        if len(regions) == 1:
            return f"every constant rate vector of the box: {regions[0].method}"
        return f"every constant rate vector of the box: {len(regions)} sub-boxes proved ({boxes} examined)"
    if verdict == "not stable" and regions:
        w = regions[-1]
        enc = "" if w.enclosure is None else f", abscissa in [{w.enclosure[0]:.6g}, {w.enclosure[1]:.6g}]"
        return f"rates {w.rate_min.tolist()}: {w.method}{enc}"
    if regions:
        w = regions[-1]
        return (f"gave up on the sub-box {w.rate_min.tolist()} .. {w.rate_max.tolist()}: {w.method} "
                f"({len(regions) - 1} sub-boxes proved stable)")
    return "nothing proved"


def _ascent(nominal: ClosedLoop, vertex: Any, widths: list[float]) -> dict[tuple[bool, ...], float] | None:
    """:func:`~ftc_verify.analysis.moments.matrix_free.linearised_ascent` above :data:`DENSE_LIMIT` rows."""
    if generator_size(nominal) <= DENSE_LIMIT or not widths:
        return None
    from .matrix_free import linearised_ascent

    return linearised_ascent(nominal, vertex, widths)


def mean_square_stability(loop: ClosedLoop, *, max_vertices: int = 256,
                          budget_seconds: float = BOX_BUDGET_SECONDS, root_lmi: bool = True) -> MSSResult:
    """The verified verdict over the whole rate box (``beta``, and the false-alarm rates
    when given; :func:`~ftc_verify.analysis.box.box_stability`, with its ``budget_seconds``
    and ``root_lmi``) and the float estimate of the worst spectral abscissa over its vertices.

    At a detection rate 0 (a missed detection) the verdict is about an FDI that never
    detects that fault (:mod:`ftc_verify.analysis.lmi`). The loop is first moved to the coordinates of
    :func:`~ftc_verify.analysis.conditioning.conditioning_transform`. Above
    :data:`DENSE_LIMIT` rows (ARPACK, seconds per vertex) the estimate is the vertex
    ascent of :func:`~ftc_verify.analysis.moments.matrix_free.linearised_ascent`
    (``exhaustive=False``). Otherwise every vertex is evaluated when there are at most
    ``max_vertices``, else a greedy vertex ascent with that budget; a vertex that
    :func:`abscissa_below` shows below the worst value so far needs no eigenvalues, the
    others get :func:`abscissa_near` (:func:`spectral_abscissa` at the first vertex, when that
    fails, and where the chain has several :func:`communicating_classes`: it stalls there).
    The box proof starts at the worst vertex found when its abscissa is not negative
    beyond :data:`~ftc_verify.analysis.box.SUSPECT_MARGIN` (an instability proof there); one it finds elsewhere raises the estimate to it."""
    sim = conditioning_transform(loop.nominal())
    nominal = sim.apply(loop.nominal())
    chain, norms = loop.chain, [float(np.linalg.norm(a, 2)) for a in nominal.A]  # norms: the shift test's margin
    prune = SHIFT_TEST_MIN <= generator_size(nominal) <= SHIFT_TEST_LIMIT
    modes_part = sparse_mode_blocks(nominal) if prune and generator_size(nominal) <= DENSE_LIMIT else None
    exact: dict[tuple[bool, ...], float] = {}
    seen: set[tuple[bool, ...]] = set()
    pairs = chain.rate_indices  # beta pairs first, then the false-alarm pairs (chain.vertices() order)
    lo, hi = chain.rate_min, chain.rate_max

    def vertex(bits: tuple[bool, ...]) -> Matrix:
        b = np.zeros(chain.rate_shape)
        for idx, up in zip(pairs, bits):
            b[idx] = hi[idx] if up else lo[idx]
        return b

    def value(bits: tuple[bool, ...], near: float | None = None) -> float:
        seen.add(bits)
        if bits not in exact:
            mu = None if near is None or modes_part is None or len(communicating_classes(chain.generator(
                vertex(bits)))) > 1 else abscissa_near(nominal, vertex(bits), near, modes_part=modes_part, norms=norms)
            exact[bits] = spectral_abscissa(nominal, vertex(bits)) if mu is None else mu
        return exact[bits]

    def above(bits: tuple[bool, ...], level: float) -> bool:
        """Exactly: abscissa at ``bits`` > ``level`` (the shift test first, then the
        abscissa by :func:`abscissa_near`, dense eigenvalues only if that fails)."""
        seen.add(bits)
        if bits in exact or not (prune and math.isfinite(level)):
            return value(bits) > level
        if abscissa_below(nominal, vertex(bits), level, modes_part=modes_part, norms=norms):
            return False
        return value(bits, near=level) > level

    def result(worst: tuple[bool, ...], evaluated: list[tuple[bool, ...]], exhaustive: bool) -> MSSResult:
        """The float estimate over the vertices evaluated and the verdict over the box."""
        estimate, where = exact[worst], vertex(worst)
        box = box_stability(loop, sim, budget_seconds=budget_seconds, root_lmi=root_lmi,
                            suspect=where if estimate >= -SUSPECT_MARGIN * max(norms, default=1.0) else None)
        witness = box.witness
        if witness is not None and witness.estimate is not None and witness.estimate > estimate:
            estimate, where = witness.estimate, witness.rate_min
        return MSSResult(estimate, where, len(evaluated), exhaustive, len(exact), box.verdict, box.regions, sim,
                         box.time_varying, box.boxes, box.reason)

    found = _ascent(nominal, vertex, [float(hi[idx] - lo[idx]) for idx in pairs])
    if found:  # above DENSE_LIMIT rows: ARPACK at a few vertices, not at all
        exact.update(found)
        return result(max(found, key=lambda k: found[k]), list(found), False)
    if chain.vertex_count() <= max_vertices:
        ends = [(False, True) if lo[idx] != hi[idx] else (False,) for idx in pairs]
        order = list(itertools.product(*ends))  # the order of chain.vertices()
        worst = order[0]
        value(worst)
        for bits in order[1:]:
            if above(bits, exact[worst]):
                worst = bits
        return result(worst, order, True)
    for start in ((False,) * len(pairs), (True,) * len(pairs)):
        if start not in seen and len(seen) >= max_vertices:
            break
        value(start)
        bits, improved = start, True
        while improved:
            improved = False
            for k in range(len(pairs)):
                cand = bits[:k] + (not bits[k],) + bits[k + 1:]
                if cand not in seen and len(seen) >= max_vertices:
                    break
                if above(cand, value(bits)):
                    bits, improved = cand, True
    return result(max(exact, key=lambda k: exact[k]), list(seen), False)
