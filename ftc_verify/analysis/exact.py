r"""The closed loop as the user wrote it, enclosed in ball arithmetic.

Every proof of :mod:`ftc_verify.analysis` (stability verdicts, the Theorem 3.1 / 3.2 and
Lemma 4.1 certificates, the lower bounds of :mod:`ftc_verify.analysis.lower_bound`) is
checked on the enclosures made here, not on a closed loop formed in float64. Two
roundings separate a float loop from the numbers in the user's files:

1. **Reading.** A decimal ``d`` written in a TOML file is read as the nearest float
   ``f``; round to nearest gives :math:`|d - f| \le 2^{-53} |f|` for a normal ``f`` and
   :math:`\le 2^{-1075}` for a subnormal one. :func:`written` encloses every entry by
   the ball :math:`f \pm (2^{-53}|f| + 2^{-1074})` (an exact zero stays exact: ``0`` is
   read exactly). Data given as floats from Python lie inside the same balls.
2. **Forming the loop.** :math:`A_i + B_i D_{c,j} M_i` in float64 loses
   :math:`\approx \varepsilon \|B_i\|\|D_{c,j}\|` per entry, which for gains of
   :math:`10^7` is far more than the loop's own margin. :func:`exact_loop` forms every
   product of :mod:`ftc_verify.analysis.closedloop`'s module docstring (the state matrix,
   the dynamic controller's blocks, the uncertainty channels) in ball arithmetic from
   the enclosures of 1.

So a certificate proved on :func:`exact_loop` holds for the exact numbers the user
wrote. A loop that :func:`~ftc_verify.analysis.closedloop.closed_loop` did not build from
a system and a controller (a loop assembled by hand, or moved to other coordinates) has
no written source; its float matrices are then the data, and their balls are exact.

Rates: :func:`enclose` encloses a rate the same way, and :func:`written_box`
rounds the ends of the rate box outward by one unit in the last place, so that a box of
floats contains the box the user wrote.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from ..model.chain import JointChain
from ..model.system import Matrix
from .closedloop import Channel, ClosedLoop
from .rigorous import Ball, ball, ball_bmat

__all__ = ["WRITTEN_RTOL", "Literals", "enclose", "written", "ball_generator", "literals_of", "written_box",
           "exact_loop", "float_balls", "ball_matrices"]

#: Float read -> the decimal texts that were read as it (:func:`ftc_verify.model.files.read_toml`).
Literals = Mapping[float, tuple[str, ...]]

#: Relative radius of a decimal read as a float (round to nearest, binary64).
WRITTEN_RTOL = 2.0 ** -53
#: Absolute radius added for subnormal floats.
_WRITTEN_ATOL = 2.0 ** -1074


def enclose(value: float, literals: Literals | None, *, computed_exact: bool = False) -> Any:
    """The ball (``flint.arb``, at the working precision) of one number of the user's data.

    ``literals is None``: the float is the data (exact). Otherwise the float was read from
    a file: the decimal text read as it, enclosed at the working precision (the hull of
    the texts when several were read as the same float); a float with no text is a
    number the loader computed, enclosed by the read tolerance of the module docstring
    -- or, with ``computed_exact``, a point the analysis chose itself (a rate inside the
    box), exact.
    """
    import flint

    v = float(value)
    if literals is None or v == 0.0:
        return flint.arb(v)
    texts = literals.get(v)
    if texts:
        out = flint.arb(texts[0])
        for text in texts[1:]:
            out = out.union(flint.arb(text))
        return out
    return flint.arb(v) if computed_exact else flint.arb(v, abs(v) * WRITTEN_RTOL + _WRITTEN_ATOL)


def written(M: Matrix, literals: Literals | None = None) -> Ball:
    """The ball matrix of the user's numbers read as the float matrix ``M`` (:func:`enclose`
    entry by entry; module docstring, item 1)."""
    import flint

    M = np.atleast_2d(np.asarray(M, dtype=float))
    if not np.all(np.isfinite(M)):
        raise ValueError("non-finite entry in a matrix given to the rigorous check")
    out = flint.arb_mat(M.shape[0], M.shape[1])
    for r in range(M.shape[0]):
        for c in range(M.shape[1]):
            if M[r, c] != 0.0:
                out[r, c] = enclose(M[r, c], literals)
    return Ball(out)


def ball_generator(chain: JointChain, point: Matrix, literals: Literals | None = None) -> list[list[Any]]:
    r"""The generator :math:`Q` at the rate array ``point`` as balls (``arb``), from
    :meth:`~ftc_verify.model.chain.JointChain.generator_terms`: each off-diagonal entry
    the exact sum of ``coef * alpha`` and ``coef * rate`` terms on the enclosures of
    :func:`enclose` (the rates of ``point`` that are not written numbers are points of the
    box the analysis chose, exact), the diagonal their negated row sum."""
    import flint

    point = np.asarray(point, dtype=float)
    S = chain.n_states
    Q = [[flint.arb(0) for _ in range(S)] for _ in range(S)]
    for s, t, coef, kind, index in chain.generator_terms():
        value = chain.alpha[index] if kind == "alpha" else point[index]
        if value != 0.0:
            Q[s][t] += coef * enclose(value, literals, computed_exact=kind == "rate")
    for s in range(S):
        Q[s][s] = -sum((Q[s][t] for t in range(S) if t != s), flint.arb(0))
    return Q


def literals_of(loop: ClosedLoop) -> Literals | None:
    """The system file's numbers as written, when the loop was formed from a system file."""
    return None if loop.source is None else loop.source[0].literals


def written_box(lo: Matrix, hi: Matrix) -> tuple[Matrix, Matrix]:
    """The rate box ``[lo, hi]`` rounded outward by one unit in the last place (a lower
    end of 0 stays 0: rates are nonnegative and 0 is read exactly), so that it contains
    every box of decimals read as these floats."""
    lo = np.asarray(lo, dtype=float)
    hi = np.asarray(hi, dtype=float)
    out_lo = np.where(lo > 0, np.nextafter(lo, -np.inf), lo)
    out_hi = np.where(hi > 0, np.nextafter(hi, np.inf), hi)
    return np.where(lo == hi, lo, out_lo), np.where(lo == hi, hi, out_hi)


def float_balls(loop: ClosedLoop) -> ClosedLoop:
    """``loop`` with every matrix the exact ball of its float entries."""
    def b(M: Matrix) -> Any:
        return ball(M)

    return replace(loop, A=tuple(b(A) for A in loop.A), Bw=tuple(b(B) for B in loop.Bw),
                   Cz=tuple(b(C) for C in loop.Cz),
                   channels=tuple(tuple(Channel(b(ch.E), b(ch.F), ch.name) for ch in chans)
                                  for chans in loop.channels))


def _zeros(rows: int, cols: int) -> Ball:
    return ball(np.zeros((rows, cols)))


def _pair_blocks(mode: Any, entry: tuple[Matrix, Matrix, Matrix, Matrix], measurement: Matrix | None,
                 n_c: int, plant: Literals | None, ctrl: Literals | None) -> tuple[Ball, Ball, Ball, list[Channel]]:
    """``(A_s, Bw_s, Cz_s, channels)`` of one pair in ball arithmetic
    (:mod:`ftc_verify.analysis.closedloop`, module docstring); ``plant`` and ``ctrl`` are
    the literals of the system and controller files."""
    def wp(M: Matrix) -> Ball:
        return written(M, plant)

    A, B, C, D = (wp(getattr(mode, k)) for k in ("A", "B", "C", "D"))
    Ac, Bc, Cc, Dc = entry
    M = wp(measurement) if measurement is not None else None
    DcM = written(Dc, ctrl) @ M if M is not None else written(Dc, ctrl)
    chans: list[Channel] = []
    if n_c == 0:
        As = A + B @ DcM
        if mode.A1 is not None and mode.A2 is not None:
            chans.append(Channel(wp(mode.A1), wp(mode.A2), "Delta1 (A)"))  # type: ignore[arg-type]
        if mode.B1 is not None and mode.B2 is not None:
            chans.append(Channel(wp(mode.B1), wp(mode.B2) @ DcM, "Delta2 (B)"))  # type: ignore[arg-type]
        return As, D, C, chans
    Acb, Bcb, Ccb = written(Ac, ctrl), written(Bc, ctrl), written(Cc, ctrl)
    BcM = Bcb @ M if M is not None else Bcb
    As = ball_bmat([[A + B @ DcM, B @ Ccb], [BcM, Acb]])
    Bw = ball_bmat([[D], [_zeros(n_c, D.shape[1])]])
    Cz = ball_bmat([[C, _zeros(C.shape[0], n_c)]])
    if mode.A1 is not None and mode.A2 is not None:
        E = ball_bmat([[wp(mode.A1)], [_zeros(n_c, mode.A1.shape[1])]])
        F = ball_bmat([[wp(mode.A2), _zeros(mode.A2.shape[0], n_c)]])
        chans.append(Channel(E, F, "Delta1 (A)"))  # type: ignore[arg-type]
    if mode.B1 is not None and mode.B2 is not None:
        B2 = wp(mode.B2)
        E = ball_bmat([[wp(mode.B1)], [_zeros(n_c, mode.B1.shape[1])]])
        F = ball_bmat([[B2 @ DcM, B2 @ Ccb]])
        chans.append(Channel(E, F, "Delta2 (B)"))  # type: ignore[arg-type]
    return As, Bw, Cz, chans


def exact_loop(loop: ClosedLoop) -> ClosedLoop:
    """``loop`` with every matrix a :class:`~ftc_verify.analysis.rigorous.Ball` that
    encloses the loop formed from the numbers the user wrote (module docstring).

    Uses ``loop.source`` (the system and controller that
    :func:`~ftc_verify.analysis.closedloop.closed_loop` recorded); without one, the
    exact balls of the float matrices (:func:`float_balls`). A nominal loop (no channels)
    stays nominal; ``source`` is kept, so that :func:`literals_of` still finds the written
    rates. Call inside :func:`~ftc_verify.analysis.rigorous.precision`.
    """
    if loop.source is None:
        return float_balls(loop)
    system, controller = loop.source
    m = system.m
    cache: dict[tuple[int, int], tuple[Ball, Ball, Ball, list[Channel]]] = {}
    A: list[Any] = []
    Bw: list[Any] = []
    Cz: list[Any] = []
    chans: list[tuple[Channel, ...]] = []
    nominal = not loop.uncertain
    for pair in loop.chain.joint_modes:
        if pair not in cache:
            i, j = pair
            mode = system.modes[i]
            k = controller.index(i, j, m)
            entry = (controller.Ac[k], controller.Bc[k], controller.Cc[k], controller.Dc[k])
            meas = None if controller.measures == "state" else controller.measurement(mode)
            cache[pair] = _pair_blocks(mode, entry, meas, controller.n_c, system.literals, controller.literals)
        a, b, c, ch = cache[pair]
        A.append(a)
        Bw.append(b)
        Cz.append(c)
        chans.append(() if nominal else tuple(ch))
    if not all(_encloses(a, af) for a, af in zip(A, loop.A)):
        return float_balls(loop)  # the source does not describe these matrices (a bug guard)
    return replace(loop, A=tuple(A), Bw=tuple(Bw), Cz=tuple(Cz), channels=tuple(chans))


def ball_matrices(matrices: Sequence[Any]) -> tuple[Ball, ...]:
    """The matrices of a loop made by :func:`exact_loop` (typed as balls)."""
    out = tuple(m for m in matrices if isinstance(m, Ball))
    if len(out) != len(matrices):
        raise TypeError("ball_matrices: a matrix is not a Ball (not a loop made by exact_loop)")
    return out


def _encloses(exact: Ball, approx: Matrix) -> bool:
    """The float loop matrix is the rounded exact one, up to the rounding of forming it
    in float64 (a loop whose source is stale fails this by far)."""
    from .rigorous import midpoint

    mid = midpoint(exact)
    approx = np.asarray(approx, dtype=float)
    if mid.shape != approx.shape:
        return False
    scale = max(float(np.abs(mid).max(initial=0.0)), float(np.abs(approx).max(initial=0.0)), 1e-300)
    return bool(np.abs(mid - approx).max(initial=0.0) <= 1e-6 * scale)
