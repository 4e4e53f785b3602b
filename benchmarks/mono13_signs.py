r"""mono13 (issue 31 item 2): float64 measurements for a monotonicity test of the radius.

Held-out ``n = 4, m = 3`` loops (``h_max_diagnosis.the_loop``, drawn as
``h_max_heldout.draw``), ``h = a (1 - f)`` with ``a`` the bracket's crossing; the design
and the results are on ``benchmarks/results/mono13.md``. Modes:

``signs``: the derivative of the radius *into* the box per free rate, at random rates
(half concentrated near the worst vertex), by the Perron formula
:math:`d\rho/d\beta_a = \langle w, J_a v\rangle / \langle w, v\rangle`; where it is
positive (the radius grows into the box) the smallest margin ``1 - rho`` there.
``kappa``: at the worst vertex, each rate's derivative and the cancellation
``(<w, J+ v> + <w, J- v>) / |<w, J v>|``.

``widths``: sub-boxes at the worst vertex; the best-case order-interval test
(``box_test``): the Perron vectors at the sub-box's vertices and random points, scaled
per joint state into ``a_s X0_s <= c x_s <= b_s X0_s``, and :math:`J_a^\pm` either at
the midpoint (``exact``) or from the envelope generators (``env``; the rigorous design).
Prints per rate the test's bound divided by the midpoint's :math:`|\langle w, J_a
v\rangle|` (``> 0``: decided). ``cells``: the same on random aligned cells.

``hilbert``: the Hilbert-ball enclosure ``R = delta_k / (1 - tau_k)`` and the test with
it; ``birkhoff``: sampled projective diameters of ``T^k`` at the vertex.

    python benchmarks/mono13_signs.py signs 13 1e-3 300
    python benchmarks/mono13_signs.py kappa 13 1e-3
    python benchmarks/mono13_signs.py widths 13 1e-3 3 5 3,3,3,x,x,3
    python benchmarks/mono13_signs.py cells 13 1e-3 3,3,3,x,x,3 16
    python benchmarks/mono13_signs.py hilbert 13 1e-3 8,16 5 x,5,x,x,x,x      (add ``,sampled`` to the powers)
    python benchmarks/mono13_signs.py birkhoff 13 1e-3 1,2,4,8,16

(a width spec per sub-box: one ``k`` for every rate, or one per free rate in the order
of ``generator_coefficients``, ``x`` = a point in that rate).
"""

from __future__ import annotations

import itertools
import sys

import numpy as np
import scipy.linalg

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from h_max_diagnosis import bracket_crossing, the_loop

from ftc_verify.analysis.moments.sampled import assemble_map, one_period_map, rate_points
from ftc_verify.analysis.moments.sampled_balls import generator_coefficients
from ftc_verify.analysis.moments.sampled_bracket import worst_vertex
from ftc_verify.analysis.moments.vech import unvech_stack


def perron(T: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """``(rho, x, y)``: the radius, the right and left Perron vectors (``sum x = 1``,
    ``y . x = 1``)."""
    lam, V = scipy.linalg.eig(T)
    k = int(np.argmax(lam.real))
    x = np.real(V[:, k])
    x = x / x.sum()
    lam2, U = scipy.linalg.eig(T.T)
    y = np.real(U[:, int(np.argmax(lam2.real))])
    return float(lam[k].real), x, y / (y @ x)


class Setup:
    def __init__(self, seed: int, f: float) -> None:
        self.loop = loop = the_loop(4, 3, seed)
        chain = loop.chain
        self.a = bracket_crossing(loop)
        self.h = self.a * (1 - f)
        rho, v = worst_vertex(loop, self.h, list(rate_points(chain)))
        self.rho, self.v = rho, np.asarray(v, float)
        self.lo, self.hi = np.asarray(chain.rate_min, float), np.asarray(chain.rate_max, float)
        full = self.hi - self.lo
        self.free = [(idx, c) for idx, c in generator_coefficients(chain)[1] if full[idx] > 0]
        self.inward = {idx: (-1.0 if self.v[idx] == self.hi[idx] else 1.0) for idx, _ in self.free}
        self.vd = loop.d * (loop.d + 1) // 2

    def generator(self, rates: np.ndarray) -> np.ndarray:
        return self.loop.modes_part + np.kron(self.loop.chain.generator(rates).T, np.eye(self.vd))

    def envelope(self, lo: np.ndarray, hi: np.ndarray, up: bool) -> np.ndarray:
        """The generator with the off-diagonal rates at ``hi`` and the diagonal at ``lo``
        (``up``), or the reverse."""
        Qa, Qb = self.loop.chain.generator(hi if up else lo), self.loop.chain.generator(lo if up else hi)
        Q = np.where(np.eye(len(Qa), dtype=bool), Qb, Qa)
        return self.loop.modes_part + np.kron(Q.T, np.eye(self.vd))

    def parts(self, coef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(G+, G-)`` of a rate with generator coefficient ``coef``."""
        off = np.where(np.eye(len(coef), dtype=bool), 0.0, coef)
        return np.kron(off.T, np.eye(self.vd)), np.kron(np.diag(-np.diag(coef)), np.eye(self.vd))

    def J(self, L: np.ndarray, G: np.ndarray) -> np.ndarray:
        D = scipy.linalg.expm_frechet(L * self.h, G * self.h, compute_expm=False)
        return assemble_map(self.loop, D, self.h)

    def map(self, rates: np.ndarray) -> np.ndarray:
        return one_period_map(self.loop, self.h, rates, scaled=True)


def signs(s: Setup, n: int) -> None:
    full = s.hi - s.lo
    rng = np.random.default_rng(1)
    stats = {idx: [np.inf, -np.inf, np.inf, 0] for idx, _ in s.free}  # min, max, least margin where > 0, count > 0
    for k in range(n):
        u = rng.uniform(size=len(s.free)) ** (1 if k % 2 else 3)
        x = s.v.copy()
        for j, (idx, _) in enumerate(s.free):
            x[idx] = s.v[idx] + s.inward[idx] * u[j] * full[idx]
        rho, pv, pw = perron(s.map(x))
        L = s.generator(x)
        for idx, coef in s.free:
            Gp, Gm = s.parts(coef)
            d = s.inward[idx] * (pw @ s.J(L, Gp - Gm) @ pv)
            st = stats[idx]
            st[0], st[1] = min(st[0], d), max(st[1], d)
            if d > 0:
                st[2], st[3] = min(st[2], 1 - rho), st[3] + 1
    print(f"worst vertex rho {s.rho:.6f} margin {1 - s.rho:.2e} a {s.a:.6f}")
    for idx, _ in s.free:
        lo, hi, m, c = stats[idx]
        print(f"  rate {idx}: d rho/d(into) in [{lo:.2e}, {hi:.2e}]; > 0 at {c}/{n}, least margin there {m:.3f}")


def kappa(s: Setup) -> None:
    """At the worst vertex, per rate: ``d rho / d beta`` and the cancellation
    ``(<w, J+ v> + <w, J- v>) / |<w, J v>|`` (the relative precision the test needs)."""
    _, x, y = perron(s.map(s.v))
    L = s.generator(s.v)
    out = []
    for idx, coef in s.free:
        Gp, Gm = s.parts(coef)
        jp, jm = y @ s.J(L, Gp) @ x, y @ s.J(L, Gm) @ x
        out.append(f"{idx}: d {jp - jm:+.2e} cancel {(jp + jm) / abs(jp - jm):.1f}")
    print(f"margin {1 - s.rho:.2e} | " + " | ".join(out))


def order_scales(blocks0: np.ndarray, samples: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Per joint state the least ``b_s`` and the largest ``a_s`` with
    ``a_s X0_s <= X_s <= b_s X0_s`` for every sample stack ``X``."""
    S = len(blocks0)
    a, b = np.full(S, np.inf), np.zeros(S)
    for X in samples:
        for t in range(S):
            ev = scipy.linalg.eigh(X[t], blocks0[t], eigvals_only=True)
            a[t], b[t] = min(a[t], ev[0]), max(b[t], ev[-1])
    return a, b


def halved(y: np.ndarray, S: int, r: int) -> np.ndarray:
    """The stack ``W`` with ``y . x = sum_s tr(W_s X_s)`` (off-diagonal entries halved)."""
    W = unvech_stack(y, S, r)
    return W - 0.5 * (W - np.einsum("sij,ij->sij", W, np.eye(r)))


def box_test(s: Setup, lo: np.ndarray, hi: np.ndarray, rng: np.random.Generator,
             rand: int = 16) -> tuple[float, dict[tuple[int, ...], tuple[float, float, float]]]:
    """The best-case test on the sub-box ``[lo, hi]``: ``(spread, {rate: (d, exact, env)})``
    with ``d`` the midpoint's ``|d rho / d beta|`` and ``exact`` / ``env`` the test's bound
    divided by it (``> 0``: the midpoint's sign is decided on the whole sub-box)."""
    S, r = s.loop.states, s.loop.r
    mid = 0.5 * (lo + hi)
    _, x0, y0 = perron(s.map(mid))
    pts = [np.array(c) for c in itertools.product((0.0, 1.0), repeat=len(s.free))]
    pts += [rng.uniform(size=len(s.free)) for _ in range(rand)]
    wide = np.array([hi[idx] > lo[idx] for idx, _ in s.free], dtype=float)
    pts = list({tuple(wide * p): p for p in pts}.values())  # a thin rate: its vertices coincide
    xs, ys = [], []
    for p in pts:
        rates = lo.copy()
        for j, (idx, _) in enumerate(s.free):
            rates[idx] = lo[idx] + p[j] * (hi[idx] - lo[idx])
        _, x, y = perron(s.map(rates))
        xs.append(unvech_stack(x / (y0 @ x), S, r))
        ys.append(halved(y / (y @ x0), S, r))
    X0, W0 = unvech_stack(x0, S, r), halved(y0, S, r)
    ax, bx = order_scales(X0, xs)
    aw, bw = order_scales(W0, ys)
    Lm, Lup, Ldn = s.generator(mid), s.envelope(lo, hi, True), s.envelope(lo, hi, False)
    out = {}
    for idx, coef in s.free:
        Gp, Gm = s.parts(coef)
        d = y0 @ s.J(Lm, Gp - Gm) @ x0
        sgn = 1.0 if d > 0 else -1.0
        vals = []
        for Jp_hi, Jp_lo, Jm_hi, Jm_lo in ((s.J(Lm, Gp),) * 2 + (s.J(Lm, Gm),) * 2,
                                           (s.J(Lup, Gp), s.J(Ldn, Gp), s.J(Lup, Gm), s.J(Ldn, Gm))):
            plus_hi = bw @ pair_matrix(y0, x0, Jp_hi, S) @ bx
            plus_lo = aw @ pair_matrix(y0, x0, Jp_lo, S) @ ax
            minus_hi = bw @ pair_matrix(y0, x0, Jm_hi, S) @ bx
            minus_lo = aw @ pair_matrix(y0, x0, Jm_lo, S) @ ax
            # d > 0: the lower bound plus_lo - minus_hi must be > 0; d < 0: the upper bound plus_hi - minus_lo < 0
            vals.append(((plus_lo - minus_hi) if sgn > 0 else -(plus_hi - minus_lo)) / abs(d))
        out[idx] = (abs(d), vals[0], vals[1])
    return max(float(np.max(bx / ax)), float(np.max(bw / aw))), out


def vertex_box(s: Setup, spec: list[float], offset: list[float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The sub-box of relative widths ``2^-spec`` (``inf``: thin) whose corner is the worst
    vertex moved inward by ``offset`` (relative) per free rate."""
    full = s.hi - s.lo
    lo, hi = s.v.copy(), s.v.copy()
    for j, ((idx, _), k) in enumerate(zip(s.free, spec)):
        start = s.v[idx] + s.inward[idx] * (0.0 if offset is None else offset[j]) * full[idx]
        other = start + s.inward[idx] * 2.0 ** -k * full[idx]
        lo[idx], hi[idx] = min(start, other), max(start, other)
    return lo, hi


def widths(s: Setup, specs: list[list[float]]) -> None:
    rng = np.random.default_rng(0)
    print(f"worst vertex rho {s.rho:.6f} margin {1 - s.rho:.2e}")
    for spec in specs:
        spread, res = box_test(s, *vertex_box(s, spec), rng)
        out = [f"{idx}: d {d:.1e} exact {ex:+.2f} env {env:+.2f}" for idx, (d, ex, env) in res.items()]
        label = ",".join("x" if k == np.inf else str(int(k)) for k in spec)
        print(f"widths 2^-[{label}]: spread b/a <= {spread:.3f} | " + " | ".join(out), flush=True)


def cells(s: Setup, spec: list[float], n: int) -> None:
    """``n`` random aligned cells of relative widths ``2^-spec`` (thin rates stay at the
    worst vertex): the margin at the cell's corner nearest the vertex and the rates whose
    sign the best-case test decides (``env``)."""
    rng = np.random.default_rng(5)
    decided = dict.fromkeys((idx for idx, _ in s.free), 0)
    for _ in range(n):
        offset = [0.0 if k == np.inf else rng.integers(0, 2 ** int(k)) * 2.0 ** -k for k in spec]
        lo, hi = vertex_box(s, spec, offset)
        corner = s.v.copy()
        for j, (idx, _) in enumerate(s.free):
            corner[idx] = s.v[idx] + s.inward[idx] * offset[j] * (s.hi[idx] - s.lo[idx])
        rho = perron(s.map(corner))[0]
        spread, res = box_test(s, lo, hi, rng, rand=8)
        ok = [idx for idx, (_, _, env) in res.items() if env > 0 and hi[idx] > lo[idx]]
        for idx in ok:
            decided[idx] += 1
        print(f"cell at {np.round(offset, 3).tolist()}: margin {1 - rho:.2e} spread {spread:.2f} decided {ok}", flush=True)
    print("decided per rate:", {str(k): f"{v}/{n}" for k, v in decided.items()})


def pair_matrix(y0: np.ndarray, x0: np.ndarray, J: np.ndarray, S: int) -> np.ndarray:
    """``M[t, s] = <W0_t, (J X0^{(s)})_t>``: the part of ``y0 . J x0`` from block ``s`` of
    ``x0`` into block ``t`` (nonnegative for a positive ``J``), so that
    ``<W_hi, J V_hi> = bw . M . bx`` when ``W_hi_t = bw_t W0_t``, ``V_hi_s = bx_s X0_s``."""
    n = len(x0) // S
    return (y0.reshape(S, n)[:, :, None, None] * J.reshape(S, n, S, n) * x0.reshape(S, n)[None, None, :, :]).sum(axis=(1, 3))


def hilbert(X: np.ndarray, Y: np.ndarray) -> float:
    """Hilbert's projective distance of two stacks of positive definite blocks (``inf``
    when a block is singular)."""
    try:
        up = max(scipy.linalg.eigh(x, y, eigvals_only=True)[-1] for x, y in zip(X, Y))
        down = max(scipy.linalg.eigh(y, x, eigvals_only=True)[-1] for x, y in zip(X, Y))
    except (np.linalg.LinAlgError, ValueError):
        return np.inf
    return float(np.log(up * down))


def birkhoff(s: Setup, powers: list[int], rays: int = 60) -> None:
    """A lower estimate of the projective diameter of ``T^k`` (the cone's image) at the
    worst vertex from ``rays`` random rank-one stacks (one state, ``z z^T``), and the
    Birkhoff contraction ``tanh(diameter / 4)`` it implies (a lower bound of it)."""
    S, r = s.loop.states, s.loop.r
    T = s.map(s.v)
    rng = np.random.default_rng(2)
    images0 = []
    for j in range(rays):
        z = rng.normal(size=r)
        X = np.zeros((S, r, r))
        X[j % S] = np.outer(z, z)
        images0.append(np.concatenate([vech_of(B) for B in X]))
    for k in powers:
        Tk = np.linalg.matrix_power(T, k)
        imgs = [unvech_stack(Tk @ x, S, r) for x in images0]
        least = min(float(np.min(np.linalg.eigvalsh(B))) / float(np.max(np.linalg.eigvalsh(B))) for im in imgs for B in im)
        diam = max(hilbert(a, b) for a, b in itertools.combinations(imgs, 2))
        print(f"T^{k}: least eigenvalue ratio of an image block {least:.1e}; diameter >= {diam:.2f}, "
              f"tau >= {np.tanh(diam / 4):.4f}")


def ratio_bounds(X: np.ndarray, X0: np.ndarray) -> tuple[float, float]:
    """``(m, M)``: the largest ``m`` and least ``M`` with ``m X0 <= X <= M X0`` (per block)."""
    ev = [scipy.linalg.eigh(x, y, eigvals_only=True) for x, y in zip(X, X0)]
    return min(e[0] for e in ev), max(e[-1] for e in ev)


def contraction(Tk: np.ndarray, X0: np.ndarray, to_vec, from_vec, rays: int = 300) -> float:
    """The Birkhoff coefficient ``tanh(Delta / 4)`` of the map ``Tk`` from the design's
    bound ``Delta <= 2 sup_E d(Tk E, X0)`` over rank-one stacks ``E`` (one state,
    ``z z^T``), the sup over ``rays`` random ``z`` per state (an estimate from below)."""
    S, r = X0.shape[0], X0.shape[1]
    rng = np.random.default_rng(3)
    worst = 0.0
    for s in range(S):
        E = np.zeros((S, r, r))
        for _ in range(rays):
            z = rng.normal(size=r)
            E[s] = np.outer(z, z)
            m, M = ratio_bounds(from_vec(Tk @ to_vec(E)), X0)
            worst = max(worst, np.log(M / m) if m > 0 else np.inf)
    return float(np.tanh(2 * worst / 4))


def hilbert_test(s: Setup, specs: list[list[float]], powers: list[int], sampled: bool = False) -> None:
    """The Hilbert-ball enclosure of the design: ``R = delta_k / (1 - tau_k)`` for the
    right and the left Perron vectors over a vertex sub-box, and each rate's test with
    the uniform order intervals ``[X0, e^R X0]``; ``delta_k`` from the envelope maps, or
    (``sampled``) the largest ``d(T(beta)^k X0, X0)`` at the sub-box's vertices and 8
    random rates (the best case of an enclosure tighter than the envelopes')."""
    loop, S, r = s.loop, s.loop.states, s.loop.r
    full = s.hi - s.lo
    xv = lambda X: np.concatenate([vech_of(B) for B in X])  # noqa: E731
    yv = lambda W: np.concatenate([vech_of(2 * B - np.diag(np.diag(B))) for B in W])  # noqa: E731
    xs = lambda v: unvech_stack(v, S, r)  # noqa: E731
    ws = lambda v: halved(v, S, r)  # noqa: E731
    for spec in specs:
        lo, hi = s.v.copy(), s.v.copy()
        for (idx, _), k in zip(s.free, spec):
            other = s.v[idx] + s.inward[idx] * 2.0 ** -k * full[idx]
            lo[idx], hi[idx] = min(s.v[idx], other), max(s.v[idx], other)
        mid = 0.5 * (lo + hi)
        _, x0, y0 = perron(s.map(mid))
        X0, W0 = xs(x0), ws(y0)
        Lup, Ldn = s.envelope(lo, hi, True), s.envelope(lo, hi, False)
        Tup = assemble_map(loop, scipy.linalg.expm(Lup * s.h), s.h)
        Tdn = assemble_map(loop, scipy.linalg.expm(Ldn * s.h), s.h)
        label = ",".join("x" if k == np.inf else str(int(k)) for k in spec)
        maps = []
        if sampled:
            rng = np.random.default_rng(4)
            wide = [idx for idx, _ in s.free if hi[idx] > lo[idx]]
            pts = [np.array(c) for c in itertools.product((0.0, 1.0), repeat=len(wide))]
            for p in pts + [rng.uniform(size=len(wide)) for _ in range(8)]:
                rates = lo.copy()
                for j, idx in enumerate(wide):
                    rates[idx] = lo[idx] + p[j] * (hi[idx] - lo[idx])
                maps.append(s.map(rates))
        for k in powers:
            Rs = []
            for fwd in (True, False):
                A, B = (Tup, Tdn) if fwd else (Tup.T, Tdn.T)
                to_vec, from_vec, Z, z = (xv, xs, X0, x0) if fwd else (yv, ws, W0, y0)
                Ak, Bk = np.linalg.matrix_power(A, k), np.linalg.matrix_power(B, k)
                delta = np.log(ratio_bounds(from_vec(Ak @ z), Z)[1] / ratio_bounds(from_vec(Bk @ z), Z)[0])
                if sampled:  # the best case of a tighter enclosure of T(beta)^k X0 than the envelopes'
                    delta = max(hilbert(from_vec(np.linalg.matrix_power(P if fwd else P.T, k) @ z), Z) for P in maps)
                tau = contraction(np.linalg.matrix_power(s.map(mid) if fwd else s.map(mid).T, k), Z, to_vec, from_vec)
                Rs.append((delta, tau, delta / (1 - tau) if tau < 1 else np.inf))
            R = Rs[0][2] + Rs[1][2]
            out = []
            for idx, coef in s.free:
                Gp, Gm = s.parts(coef)
                sgn = -s.inward[idx]
                jp = (y0 @ s.J(Lup, Gp) @ x0, y0 @ s.J(Ldn, Gp) @ x0)
                jm = (y0 @ s.J(Lup, Gm) @ x0, y0 @ s.J(Ldn, Gm) @ x0)
                # positive: jp_dn - e^R jm_up > 0; negative: e^R jp_up - jm_dn < 0
                val = (jp[1] - np.exp(R) * jm[0]) if sgn > 0 else (jm[1] - np.exp(R) * jp[0])
                out.append(f"{idx}: {val / abs(y0 @ s.J(s.generator(mid), Gp - Gm) @ x0):+.2f}")
            if not np.isfinite(R) or R > 50:
                print(f"widths 2^-[{label}] k {k}: right delta {Rs[0][0]:.3f} tau {Rs[0][1]:.3f}; left delta "
                      f"{Rs[1][0]:.3f} tau {Rs[1][1]:.3f}; R {R:.3g}: no enclosure")
                continue
            print(f"widths 2^-[{label}] k {k}: right delta {Rs[0][0]:.3f} tau {Rs[0][1]:.3f}; left delta {Rs[1][0]:.3f} "
                  f"tau {Rs[1][1]:.3f}; e^R {np.exp(R):.3f} | " + " ".join(out), flush=True)


def vech_of(B: np.ndarray) -> np.ndarray:
    rows, cols = np.tril_indices(len(B))
    order = np.lexsort((rows, cols))
    return B[rows[order], cols[order]]


if __name__ == "__main__":
    mode, seed, f = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
    setup = Setup(seed, f)
    if mode == "cells":
        cells(setup, [np.inf if x == "x" else float(x) for x in sys.argv[4].split(",")], int(sys.argv[5]))
    elif mode == "kappa":
        kappa(setup)
    elif mode == "hilbert":
        n_free = len(setup.free)
        specs = [[np.inf if x == "x" else float(x) for x in a.split(",")] for a in sys.argv[5:]]
        ks = sys.argv[4].split(",")
        hilbert_test(setup, [sp * n_free if len(sp) == 1 else sp for sp in specs], [int(x) for x in ks if x != "sampled"],
                     sampled="sampled" in ks)
    elif mode == "birkhoff":
        birkhoff(setup, [int(x) for x in sys.argv[4].split(",")])
    elif mode == "signs":
        signs(setup, int(sys.argv[4]))
    else:
        n_free = len(setup.free)
        specs = [[np.inf if x == "x" else float(x) for x in a.split(",")] for a in sys.argv[4:]]
        widths(setup, [sp * n_free if len(sp) == 1 else sp for sp in specs])
