r"""Verified mean-square stability verdicts: "stable", "not stable" or "undecided", never wrong.

The exact test of :mod:`ftc_verify.analysis.moments.stability` computes the spectral abscissa
:math:`\mu` of the second-moment generator :math:`\mathcal L` in float64; an
ill-conditioned loop can move it across zero. Here every verdict at a vertex of the
rate box (a rate array of :mod:`ftc_verify.model.chain`: ``beta``, or ``[beta,
false_alarm]``) comes with a certificate checked in ball arithmetic
(:mod:`ftc_verify.analysis.rigorous`) in the loop's *original* coordinates, from the
data as the user wrote them (:mod:`ftc_verify.analysis.exact`).

With :math:`\mathcal L(X)_s = A_s X_s + X_s A_s^T + \sum_{t} Q_{ts} X_t` (resolvent
positive: :math:`e^{\mathcal L t}` maps positive semidefinite stacks to positive
semidefinite stacks; its adjoint has an eigenvector :math:`Z \succeq 0`, :math:`Z \ne 0`,
:math:`\mathcal L^*(Z) = \mu Z`, Krein-Rutman), derived here:

* **Stable** (:math:`\mu < 0`) if some :math:`X` has :math:`X_s \succ 0` and
  :math:`-\mathcal L(X)_s \succ 0` for every joint state :math:`s`: then
  :math:`0 > \langle \mathcal L(X), Z\rangle = \mu \langle X, Z\rangle` with
  :math:`\langle X, Z\rangle > 0`.
* **Not stable** (:math:`\mu \ge 0`) if some :math:`X` has :math:`-\mathcal L(X)_s
  \succ 0` for every :math:`s` but some :math:`X_s` has a direction :math:`v` with
  :math:`v^T X_s v < 0`: were :math:`\mu < 0`, :math:`\mathcal L` would be invertible
  and :math:`X = \int_0^\infty e^{\mathcal L t}(-\mathcal L(X))\,dt \succeq 0`. (A
  witness :math:`W \succ 0` with :math:`\mathcal L(W) \succ 0` need not exist: the
  rightmost eigenvector is often of rank one.) With :math:`X` the exact solution of
  :math:`\mathcal L(X) = -I` this is the same argument.

Both arguments use only that :math:`Q` is a generator (off-diagonal rates
:math:`\ge 0`, rows summing to zero), never that the chain is irreducible: they hold on
the joint chain with detection phases and false alarms, and at a missed-detection vertex
(:math:`\beta_{ji} = 0`, the detection states of the pair absorbing), where "stable"
means stable for an FDI that never detects that fault.

The candidate :math:`X` comes from the loop in the coordinates of
:func:`~ftc_verify.analysis.conditioning.conditioning_transform` (float: solve
:math:`\tilde{\mathcal L}(\tilde X) = -I`), mapped back exactly as :math:`X = T\tilde X T^T` in ball arithmetic. When that does not
decide, :math:`\mathcal L(X) = -I` is solved in ball arithmetic (FLINT's certified
``arb_mat.solve``, an enclosure of the exact solution) at 128, then 256 and 512 bits,
within :data:`SOLVE_LIMIT` rows and a budget of CPU seconds; what is still open is "undecided".
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..jsonable import fields_dict, renamed
from ..limits import cpu_clock
from ..model.system import Matrix
from .closedloop import ClosedLoop
from .conditioning import Similarity
from .exact import ball_generator, ball_matrices, exact_loop, literals_of
from .rigorous import Ball, ball, precision, proven_not_psd, proven_positive_definite, tight_solve

__all__ = ["VERDICTS", "SOLVE_LIMIT", "BUDGET_SECONDS", "FALLBACK_BITS", "VertexVerdict", "StabilityProver",
           "certify_vertex", "combine", "describe", "ball_lyapunov_solution", "float_stack_solution"]

#: The three answers a stability verdict can give.
VERDICTS = ("stable", "not stable", "undecided")
#: Largest generator (rows) solved in ball arithmetic: FLINT's solve is one C call that a
#: signal cannot interrupt, about 1.2 s at 128 bits and 4 s at 512 bits for 400 rows here
#: (cubic in the rows), so Ctrl-C and SIGTERM are honoured within seconds.
SOLVE_LIMIT = 400
#: Budget of the ball-arithmetic fallback (of one vertex, or of the whole box in
#: :func:`~ftc_verify.analysis.moments.stability.mean_square_stability`), in CPU seconds
#: (:func:`~ftc_verify.limits.cpu_clock`, so that a verdict depends much less on the
#: machine's load).
BUDGET_SECONDS = 60.0
#: Precisions (bits) of the ball-arithmetic fallback, in order.
FALLBACK_BITS = (128, 256, 512)


@dataclass(frozen=True)
class VertexVerdict:
    """The verified verdict at one vertex (a rate array ``beta``) and how it was proved."""

    beta: Matrix
    verdict: str
    method: str
    precision_bits: int
    seconds: float
    estimate: float | None = field(default=None, metadata=renamed("float_abscissa"))

    def to_dict(self) -> dict[str, object]:
        """JSON-ready summary (the fields; ``estimate`` as ``float_abscissa``)."""
        return fields_dict(self)


def _lyapunov_operator(A: Sequence[Ball], q: list[list[Any]], X: Sequence[Ball]) -> list[Ball]:
    r""":math:`\mathcal L(X)_s` in ball arithmetic from the enclosures ``A_s`` and the
    ball generator ``q`` (module docstring)."""
    out = []
    for s, Ab in enumerate(A):
        Y = Ab @ X[s] + X[s] @ Ab.T
        for t in range(len(X)):
            if t == s or q[t][s] != 0:
                Y = Y + Ball(q[t][s] * X[t].value)
        out.append(Y)
    return out


def _float_candidate(conditioned: ClosedLoop, beta: Matrix) -> np.ndarray | None:
    """The float solution ``X~`` of ``L~(X~) = -I`` for the conditioned loop, as a stack of
    symmetric matrices (``None`` when the solve fails or is not finite)."""
    return float_stack_solution(conditioned.A, conditioned.chain.generator(beta))


def float_stack_solution(A: Sequence[Matrix], Q: Matrix, shift: float = 0.0) -> np.ndarray | None:
    r"""The float stack :math:`X` with :math:`A_s X_s + X_s A_s^T + \sum_t Q_{ts} X_t - \sigma X_s = -I`
    (:math:`\sigma` = ``shift``, the equation of
    :func:`~ftc_verify.analysis.moments.stability.abscissa_below`; with :math:`\sigma = 0`
    :func:`~ftc_verify.analysis.moments.stability.lyapunov_stack_solution`'s; a candidate, proved
    or not used). Above :data:`~ftc_verify.analysis.moments.stability.DENSE_LIMIT` rows, where that
    function factors the sparse Kronecker system (fill-in of order :math:`(m^2 n^2)^2`),
    it is :func:`~ftc_verify.analysis.bounded_real.coupled_lyapunov` first (GMRES
    preconditioned by one Schur form per joint state, :math:`O(m^2 n^3)` per product), the
    sparse factorisation only when GMRES does not converge."""
    from .moments.stability import DENSE_LIMIT, lyapunov_stack_solution

    n = A[0].shape[0]
    shifted = [a - 0.5 * shift * np.eye(n) for a in A] if shift else list(A)
    if len(A) * n * (n + 1) // 2 > DENSE_LIMIT:
        from .bounded_real import coupled_lyapunov

        X = coupled_lyapunov([a.T for a in shifted], np.asarray(Q).T, [np.eye(n)] * len(A))
        if X is not None:
            return np.array(X)
    return lyapunov_stack_solution(shifted, Q)


def _positive_definite(M: Ball, precond: Ball) -> bool:
    """Proved positive definite, preconditioned by the conditioning similarity or, when
    that fails, in the original coordinates (where a direction of a very different scale
    may be a coordinate axis that the Jacobi scaling of the proof already separates)."""
    return proven_positive_definite(M, precond) or proven_positive_definite(M)


def _decide(X: Sequence[Ball], precond: Ball) -> str | None:
    """"stable" if every ``X_s`` is proved positive definite, "not stable" if some
    ``X_s`` is proved to have a negative direction, ``None`` otherwise (``L(X) < 0``
    already known)."""
    if all(_positive_definite(x, precond) for x in X):
        return "stable"
    if any(proven_not_psd(x) for x in X):
        return "not stable"
    return None


def _ball_generator(A: Sequence[Ball], q: list[list[Any]]) -> Any:
    """The generator in vech coordinates as a ball matrix (``arb_mat``) from the ball
    matrices ``A_s``: row ``(r, c)`` of :math:`A X + X A^T` takes :math:`A_{rp}` at
    :math:`X_{pc}` and :math:`A_{cp}` at :math:`X_{rp}` (``X`` symmetric)."""
    import flint

    from .moments.stability import vech_order

    n, modes = A[0].shape[0], len(A)
    rows, cols = vech_order(n)
    index = {(int(r), int(c)): k for k, (r, c) in enumerate(zip(rows, cols))}
    h = len(rows)
    G = flint.arb_mat(modes * h, modes * h)
    for s, Ab in enumerate(A):
        a = Ab.value
        for k, (r, c) in enumerate(zip(rows, cols)):
            r, c = int(r), int(c)
            for p in range(n):
                G[s * h + k, s * h + index[max(p, c), min(p, c)]] += a[r, p]
                G[s * h + k, s * h + index[max(r, p), min(r, p)]] += a[c, p]
    for s in range(modes):
        for t in range(modes):
            value = q[t][s]  # block (s, t) of Q' kron I is Q[t, s] I
            if value != 0:
                for r in range(h):
                    G[s * h + r, t * h + r] += value
    return G


def ball_lyapunov_solution(A: Sequence[Ball], q: list[list[Any]], bits: int,
                           rhs: Sequence[Ball] | None = None) -> list[Ball] | None:
    """An enclosure of the exact solution of ``L(X) = -I`` (or ``L(X) = -R`` for the
    symmetric ball matrices ``rhs``) at ``bits`` (``None`` when FLINT cannot prove the
    system nonsingular at that precision)."""
    import flint

    from .moments.stability import vech_order

    n, modes = A[0].shape[0], len(A)
    rows, cols = vech_order(n)
    h = len(rows)
    with precision(bits):
        G = _ball_generator(A, q)
        if rhs is None:
            b = flint.arb_mat([[-1.0 if r == c else 0.0] for _ in range(modes) for r, c in zip(rows, cols)])
        else:
            b = flint.arb_mat(modes * h, 1)
            for s in range(modes):
                for k, (r, c) in enumerate(zip(rows, cols)):
                    b[s * h + k, 0] = -rhs[s].value[int(r), int(c)]
        v = tight_solve(G, b)
        if v is None:
            return None
        out = []
        for s in range(modes):
            X = flint.arb_mat(n, n)
            for k, (r, c) in enumerate(zip(rows, cols)):
                X[int(r), int(c)] = v[s * h + k, 0]
                X[int(c), int(r)] = v[s * h + k, 0]
            out.append(Ball(X))
    return out


@dataclass(frozen=True, eq=False)
class StabilityProver:
    """Proves verdicts of one loop at any ``beta`` (:meth:`certify`); the loop's
    conditioned copy and the exact balls of its data are made once."""

    nominal: ClosedLoop
    sim: Similarity
    conditioned: ClosedLoop
    A: tuple[Ball, ...]
    T: Ball
    precond: Ball
    enclosures: Callable[[], tuple[Ball, ...]] | None = None

    @classmethod
    def build(cls, loop: ClosedLoop, sim: Similarity) -> StabilityProver:
        """For the nominal part of ``loop`` and the conditioning ``sim``."""
        nominal = loop.nominal()
        with precision():
            return cls(nominal, sim, sim.apply(nominal), ball_matrices(exact_loop(nominal).A), ball(sim.T),
                       ball(sim.T_inv.T))  # C' (T X~ T') C = X~

    @classmethod
    def for_matrices(cls, loop: ClosedLoop, sim: Similarity, enclosures: Callable[[], tuple[Ball, ...]]) -> StabilityProver:
        """For the state matrices that ``enclosures()`` encloses at the working precision
        (a loop modified in ball arithmetic, such as a worst-case feedback loop), with
        ``loop`` their float version (the chain, and the float candidates)."""
        nominal = replace(loop.nominal(), source=None)
        with precision():
            return cls(nominal, sim, sim.apply(nominal), enclosures(), ball(sim.T), ball(sim.T_inv.T), enclosures)

    def _enclosures(self) -> tuple[Ball, ...]:
        return self.enclosures() if self.enclosures is not None else ball_matrices(exact_loop(self.nominal).A)

    def certify(self, beta: Matrix, *, estimate: float | None = None,
                budget_seconds: float = BUDGET_SECONDS, shift: float = 0.0) -> VertexVerdict:
        r"""The verified verdict at ``beta`` (module docstring). ``estimate`` (the float
        abscissa at ``beta``, if known) is recorded in the result only; the verdict
        never depends on it.

        ``shift`` (a float ``sigma``) decides the sign of :math:`\mu - \sigma` instead,
        on the operator :math:`\mathcal L - \sigma I`, i.e. with every :math:`A_s`
        replaced by :math:`A_s - (\sigma/2) I` (exactly, in the balls): "stable" then
        proves :math:`\mu < \sigma`, "not stable" :math:`\mu \ge \sigma`
        (the enclosure of an abscissa, :func:`abscissa_enclosure`)."""
        start, clock = time.perf_counter(), cpu_clock()
        half = 0.5 * float(shift)

        def done(verdict: str, method: str, bits: int) -> VertexVerdict:
            return VertexVerdict(np.asarray(beta, dtype=float), verdict, method, bits,
                                 time.perf_counter() - start, estimate)

        def shifted(A: Sequence[Ball]) -> tuple[Ball, ...]:
            return tuple(a if half == 0.0 else a - half * np.eye(a.shape[0]) for a in A)

        conditioned = self.conditioned
        if half != 0.0:
            conditioned = replace(conditioned, A=tuple(a - half * np.eye(a.shape[0]) for a in conditioned.A))
        Xt = _float_candidate(conditioned, beta)
        if Xt is not None:
            with precision():
                X = [self.T @ ball(0.5 * (x + x.T)) @ self.T.T for x in Xt]
                q = ball_generator(self.nominal.chain, beta, literals_of(self.nominal))
                if all(_positive_definite(-y, self.precond) for y in _lyapunov_operator(shifted(self.A), q, X)):
                    verdict = _decide(X, self.precond)
                    if verdict is not None:
                        what = "X > 0" if verdict == "stable" else "some X_s indefinite"
                        return done(verdict, f"L(X) < 0 and {what}, X from float64 in conditioned coordinates, "
                                             "checked in 128-bit balls", 128)
        size = len(self.nominal.A) * self.nominal.n * (self.nominal.n + 1) // 2
        if size > SOLVE_LIMIT:
            return done("undecided", f"float64 candidates not proved and the generator ({size} rows) is above "
                                     f"the ball-arithmetic limit ({SOLVE_LIMIT})", 0)
        for bits in FALLBACK_BITS:
            if cpu_clock() - clock >= budget_seconds:
                return done("undecided", f"budget of {budget_seconds:g} CPU s spent before {bits} bits", bits)
            with precision(bits):
                A = shifted(self._enclosures())  # the enclosures at this precision
                q = ball_generator(self.nominal.chain, beta, literals_of(self.nominal))
            solution = ball_lyapunov_solution(A, q, bits)
            if solution is None:
                continue
            with precision(bits):
                verdict = _decide(solution, self.precond)
            if verdict is not None:
                return done(verdict, f"exact solution of L(X) = -I enclosed at {bits} bits, "
                                     + ("every X_s > 0" if verdict == "stable" else "some X_s indefinite"), bits)
        return done("undecided", f"no certificate either way up to {FALLBACK_BITS[-1]} bits", FALLBACK_BITS[-1])

    def abscissa_enclosure(self, beta: Matrix, estimate: float, *,
                           budget_seconds: float = BUDGET_SECONDS) -> tuple[float, float] | None:
        """A proved enclosure ``[lo, hi)`` of the spectral abscissa at ``beta`` around the
        float ``estimate``: :meth:`certify` with ``shift = lo`` says "not stable" and
        with ``shift = hi`` "stable"; widths ``1e-9 .. 1e-3`` of ``1 + |estimate|`` are
        tried. ``None`` when none is proved."""
        deadline = cpu_clock() + budget_seconds
        for width in (1e-9, 1e-6, 1e-3):
            d = width * (1.0 + abs(estimate))
            lo, hi = estimate - d, estimate + d
            left = max(0.0, deadline - cpu_clock())
            if (self.certify(beta, shift=lo, budget_seconds=left).verdict == "not stable"
                    and self.certify(beta, shift=hi, budget_seconds=left).verdict == "stable"):
                return lo, hi
        return None


def certify_vertex(loop: ClosedLoop, beta: Matrix, sim: Similarity, *, estimate: float | None = None,
                   budget_seconds: float = BUDGET_SECONDS) -> VertexVerdict:
    """The verified verdict of the nominal ``loop`` at ``beta`` (module docstring;
    :meth:`StabilityProver.certify` for one vertex)."""
    return StabilityProver.build(loop, sim).certify(beta, estimate=estimate, budget_seconds=budget_seconds)


def combine(verdicts: Sequence[VertexVerdict]) -> str:
    """The box's verdict from its vertices': "not stable" if any vertex is, else
    "undecided" if any is, else "stable"."""
    found = {v.verdict for v in verdicts}
    if "not stable" in found:
        return "not stable"
    if "undecided" in found or not verdicts:
        return "undecided"
    return "stable"


def describe(verdicts: Sequence[VertexVerdict]) -> str:
    """One line: how the deciding vertex verdict was proved."""
    verdict = combine(verdicts)
    deciding = next((v for v in verdicts if v.verdict == verdict), None)
    if deciding is None:
        return "no vertex certified"
    if verdict == "stable":
        bits = max(v.precision_bits for v in verdicts)
        return f"every vertex: {deciding.method}" + (f" (up to {bits} bits)" if bits > 128 else "")
    return f"beta {np.asarray(deciding.beta).tolist()}: {deciding.method}"

