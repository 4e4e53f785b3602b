#!/usr/bin/env python
r"""Why the stable end of the ``h_max`` bracket stops short on a loop: the rate box at
``h = a (1 - f)`` below the worst vertex's float64 crossing ``a`` (issue 31, item 2).

For the random loop of ``benchmarks/sampled.py`` (``--n 4 --m 3 --seed 1`` is the
``n = 4, m = 3`` case of ``benchmarks/sampled.py --seed 1``) it writes one CSV row per
measured quantity:

* ``vertex_rho``: the float64 radius at the worst vertex (:func:`worst_vertex`) and
  ``sampled_max``: the largest radius at random rates of the box (uniform, and near the
  vertex) -- is the box's maximum at the vertex?
* ``slope_<rate>``: the derivative of the radius into the box at the vertex along each
  rate (per unit rate, forward difference ``1e-4``) and ``drop_<rate>``: the change of
  the radius from the vertex to the rate's other end (the others held): the "flat"
  rates are those whose whole range moves the radius by less than the margin.
* ``vertex_box_<k>``: whether the sub-box at the vertex of relative width ``2^-k`` in
  every rate is proved by the sub-box proofs (envelope, then the affine forms with the
  second-order and first-order certificates; ``sampled_proof``), and its CPU seconds.
* ``envelope_flat_<k>``: the float64 radius of the upper envelope
  (``sampled_balls.envelope_generator``) over the flat rates at relative width ``2^-k``
  (the steep ones at the vertex): the envelope proves nothing where it is >= 1.
* ``flat_box_<k>``: the sub-box at the vertex with the flat rates at relative width
  ``2^-k``, the others at ``1/32``: proved by the second-order certificate
  (``sampled_second.certify_second_order``, Perron mix 0.05) on the affine forms
  (``fast_balls.aff_map``) and on the second-order forms (``quad_balls.quad_map``), and
  their CPU seconds.
* ``box_verdict`` (``--box-cap N``): ``box_verdict`` at ``h`` with at most ``N`` sub-boxes.
* ``clock_<f>`` (``--clock f ...``): the clock-dependent certificate
  (``sampled_clock.clock_stable``, ``--pieces`` quadratic pieces) at ``a (1 - f)``.
* ``certificate_<ks>_<kf>`` (``--certificates``): on the sub-box at the vertex with the
  steep rates at ``2^-ks`` and the flat ones at ``2^-kf`` of their range, float64 with
  the *exact* map at the sub-box's 64 vertices and 40 random points: the smallest
  relative slack :math:`\lambda_{min}(Y^{-1/2}(Y - T Y) Y^{-1/2})` over joint states
  and points of a Lyapunov stack fixed at the centre (``fixed``, :math:`Y_0`), moving
  with the rates to first order (``first``, :math:`Y_0 + \sum \delta_a y_a`) and to
  second order (``second``, :math:`+ \sum \mu_p y_p`; the certificate of
  ``sampled_second``, Perron mix 0.05) -- what the rate-dependent certificate gains
  before any enclosure; then ``wrap``: the second-order form's remainder bound
  ``T_r |Y|`` (``quad_map``) over the true remainder of the map's second-order
  expansion at those points (largest ratio over joint states), and whether the rigorous
  check proves the sub-box.
* ``ordering``: the largest eigenvalue, relative to the block, of ``sign * (V_t - V_s)``
  over the clock, ``V`` the dual Perron stack at the vertex carried back over the period
  and ``s -> t`` each free rate's transition: <= 0 for every rate would prove the radius
  monotone into the box (the vertex the maximum) by a cone argument; it is not.

Usage::

    python benchmarks/h_max_diagnosis.py --seed 1 --f 1e-3 --out /tmp/diag.csv
    python benchmarks/h_max_diagnosis.py --seed 1 --f 1e-3 --box-cap 300 --clock 0.03 0.02 0.01
    python benchmarks/h_max_diagnosis.py --seed 1 --f 1e-3 --samples 0 --certificates 5:2 5:1 5:0 4:2 3:1
"""

from __future__ import annotations

import argparse
import itertools
import csv
import dataclasses
import math
import os
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
import scipy.linalg

from ftc_verify.analysis.moments import sampled_proof as sp
from ftc_verify.analysis.moments.sampled import (SampledLoop, assemble_map, crossing, one_period_map, rate_points, scan_periods,
                                                 scan_range, spectral_radius, stability_intervals)
from ftc_verify.analysis.moments.sampled_balls import envelope_generator, generator_coefficients
from ftc_verify.analysis.moments.sampled_bracket import worst_crossing, worst_vertex
from ftc_verify.analysis.moments.fast_balls import aff_map
from ftc_verify.analysis.moments.quad_balls import pairs, quad_map
from ftc_verify.analysis.moments.sampled_clock import clock_stable
from ftc_verify.analysis.moments.sampled_second import certify_second_order, second_order_choices
from ftc_verify.analysis.moments.sampled_taylor import _rates_affine, affine_stable, float_choices, left_perron, right_perron
from ftc_verify.analysis.moments.stability import unvech_stack, vech_order
from ftc_verify.analysis.rigorous import midpoint, precision
from ftc_verify.testing.sampled_cases import lqr_case


def the_loop(n: int, m: int, seed: int) -> SampledLoop:
    """The ``(n, m)`` case of ``benchmarks/sampled.py --seed seed`` (drawn after the
    ``n = 2, m = 2`` one from the same generator when ``n = 4``)."""
    rng = np.random.default_rng(seed)
    first = lqr_case(2, 2, rng)
    system, controller = first if (n, m) == (2, 2) else lqr_case(n, m, rng)
    return dataclasses.replace(SampledLoop.build(system, controller), written=(0.01,))


@dataclasses.dataclass(frozen=True)
class Rung:
    """A held-out ``n = 4, m = 3`` loop (:func:`the_loop`, conditioned as the refinement
    runs it) at a rung's period ``h = hu (1 - f)``: its map parts at ``h`` and the worst
    vertex at ``hu`` (as the cover takes them)."""

    loop: SampledLoop
    h: float
    parts: sp.MapParts
    worst: np.ndarray

    @property
    def box(self) -> tuple[np.ndarray, np.ndarray, int]:
        chain = self.loop.chain
        return np.array(chain.rate_min, dtype=float), np.array(chain.rate_max, dtype=float), 0


def rung_parser(doc: str) -> argparse.ArgumentParser:
    """The arguments every rung script takes: ``SEED HU F`` (positional) and ``--out``."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("seed", type=int)
    parser.add_argument("hu", type=float)
    parser.add_argument("f", type=float)
    parser.add_argument("--out", default=None)
    return parser


def held_out_rung(seed: int, hu: float, f: float) -> Rung:
    """The :class:`Rung` of held-out seed ``seed`` at ``hu (1 - f)``."""
    from ftc_verify.analysis.moments.sampled_conditioned import conditioned
    from ftc_verify.analysis.rigorous import precision

    loop = conditioned(the_loop(4, 3, seed))
    h = hu * (1 - f)
    with precision(64):
        parts = sp.MapParts.build(loop, h)
    return Rung(loop, h, parts, worst_vertex(loop, hu, rate_points(loop.chain))[1])


def harder_half(lo: np.ndarray, hi: np.ndarray, r: tuple[int, ...], worst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The half of ``[lo, hi]`` along rate ``r`` nearer to ``worst`` (the cover's first)."""
    mid = 0.5 * (lo[r] + hi[r])
    lo, hi = lo.copy(), hi.copy()
    if abs(worst[r] - lo[r]) <= abs(worst[r] - hi[r]):
        hi[r] = mid
    else:
        lo[r] = mid
    return lo, hi


def bracket_crossing(loop: SampledLoop) -> float:
    """The crossing ``a`` the bracket proves below (``sampled_bracket.h_max_bracket``)."""
    lo, hi = scan_range(loop, 0.01)
    hs, rhos = scan_periods(loop, lo, hi)
    iv = stability_intervals(loop, hs, rhos)
    k = int(np.searchsorted(hs, iv[0][1], side="right"))
    pts = list(rate_points(loop.chain))
    a = crossing(loop, float(hs[k - 1]), float(hs[k]), True, 1e-3 / 16, pts)
    return worst_crossing(loop, float(hs[k - 1]), a, 1e-3, pts, math.inf)


def ordering(loop: SampledLoop, h: float, v: np.ndarray, free: list[tuple[tuple[int, ...], np.ndarray]]) -> dict[str, float]:
    """The largest relative eigenvalue of ``sign (dL^* V)_s`` over 41 clock values per rate."""
    S, d, r = loop.states, loop.d, loop.r
    vd = d * (d + 1) // 2
    G = loop.modes_part + np.kron(loop.chain.generator(v).T, np.eye(vd))
    P = np.kron(np.eye(S), loop.restrict_map)
    T = P @ scipy.linalg.expm(G * h) @ scipy.linalg.block_diag(*loop.lifts(h))

    def weights(k: int) -> np.ndarray:
        rows, cols = vech_order(k)
        return np.tile(np.where(rows == cols, 1.0, 2.0), S)

    Wd, Wr = weights(d), weights(r)
    y = right_perron(np.diag(1 / Wr) @ T.T @ np.diag(Wr))  # the dual Perron stack
    if y is None:
        return {}
    Gs, Ps = np.diag(1 / Wd) @ G.T @ np.diag(Wd), np.diag(1 / Wd) @ P.T @ np.diag(Wr)
    out: dict[str, float] = {}
    for tau in np.linspace(0.0, h, 41):
        Vs = unvech_stack(scipy.linalg.expm(Gs * (h - tau)) @ Ps @ y, S, d)
        for idx, c in free:
            sign = 1.0 if v[idx] == loop.chain.rate_min[idx] else -1.0
            for s in np.nonzero(np.diag(c))[0]:
                M = sign * sum(c[s, t] * Vs[t] for t in range(S))
                val = float(np.linalg.eigvalsh(M)[-1] / np.linalg.eigvalsh(Vs[s])[-1])
                out[str(idx)] = max(out.get(str(idx), -math.inf), val)
    return out


def flat_boxes(loop: SampledLoop, parts: sp.MapParts, v: np.ndarray, inward: dict[tuple[int, ...], float],
               flat: list[tuple[int, ...]]) -> list[tuple[str, str]]:
    """Sub-boxes at the vertex: the flat rates at ``2^-k`` of their range, the others at 1/32;
    the second-order certificate on the affine and on the second-order forms."""
    chain = loop.chain
    full = chain.rate_max - chain.rate_min
    res, modes, lift, hh = parts.floats
    rows = []
    for k in (1, 2, 3, 4):
        lo, hi = v.copy(), v.copy()
        for idx, sign in inward.items():
            other = v[idx] + sign * (2.0 ** -k if idx in flat else 1 / 32) * full[idx]
            lo[idx], hi[idx] = min(v[idx], other), max(v[idx], other)
        found = _rates_affine(loop, lo, hi)
        assert found is not None
        cells = []
        for name, make in (("affine", aff_map), ("second-order", quad_map)):
            t = time.process_time()
            form = make(res, modes, found[0], found[1], hh, lift)
            with precision(64):
                ok = form is not None and certify_second_order(loop, form, 0.05)
            cells.append(f"{name} {ok} ({time.process_time() - t:.2f} CPU s)")
        rows.append((f"flat_box_{k}", "; ".join(cells)))
    return rows


def _relative_slack(loop: SampledLoop, Y: np.ndarray, TY: np.ndarray) -> float:
    """The smallest eigenvalue of ``Y_s^{-1/2} (Y - T Y)_s Y_s^{-1/2}`` over joint states."""
    out = math.inf
    for Ys, Zs in zip(unvech_stack(Y, loop.states, loop.r), unvech_stack(Y - TY, loop.states, loop.r)):
        ev, U = np.linalg.eigh(Ys)
        if ev[0] <= 0:
            return -math.inf
        W = U @ np.diag(ev ** -0.5) @ U.T
        out = min(out, float(np.linalg.eigvalsh(W @ Zs @ W)[0]))
    return out


def certificates(loop: SampledLoop, h: float, parts: sp.MapParts, v: np.ndarray, inward: dict[tuple[int, ...], float],
                 flat: list[tuple[int, ...]], widths: list[tuple[int, int]]) -> list[tuple[str, str]]:
    """The ``certificate_<ks>_<kf>`` rows (module docstring)."""
    chain, S = loop.chain, loop.states
    full = chain.rate_max - chain.rate_min
    res, modes, lift, hh = parts.floats
    rng = np.random.default_rng(0)
    rows = []
    for ks, kf in widths:
        lo, hi = v.copy(), v.copy()
        for idx, sign in inward.items():
            other = v[idx] + sign * 2.0 ** -(kf if idx in flat else ks) * full[idx]
            lo[idx], hi[idx] = min(v[idx], other), max(v[idx], other)
        found = _rates_affine(loop, lo, hi)
        form = None if found is None else quad_map(res, modes, found[0], found[1], hh, lift)
        if form is None:
            continue
        Tc, Tl, Tq, Tr = form
        choice, w = float_choices(Tc, list(Tl), S, loop.r, 0.05), left_perron(Tc)
        second = None if choice is None or w is None else second_order_choices(Tc, Tl, Tq, choice[0], np.stack(choice[1]), w)
        if second is None:
            continue
        Y0, Yl, Yq = choice[0], np.stack(choice[1]), second[0]
        idxs = list(inward)
        prs = pairs(len(idxs))
        points = [np.array(c) for c in itertools.product((-1.0, 1.0), repeat=len(idxs))]
        worst = dict.fromkeys(("fixed", "first", "second"), math.inf)
        true_rem = np.zeros_like(Y0)
        for d in points + [rng.uniform(-1, 1, len(idxs)) for _ in range(40)]:
            rates = 0.5 * (lo + hi)
            for k, idx in enumerate(idxs):
                rates[idx] += 0.5 * d[k] * (hi[idx] - lo[idx])
            T = one_period_map(loop, h, rates, scaled=True)
            mu = np.array([d[a] * d[b] for a, b in prs])
            Ys = {"fixed": Y0, "first": Y0 + d @ Yl, "second": Y0 + d @ Yl + mu @ Yq}
            for name, Y in Ys.items():
                worst[name] = min(worst[name], _relative_slack(loop, Y, T @ Y))
            poly = Tc + np.tensordot(d, Tl, 1) + np.tensordot(mu, Tq, 1)
            true_rem = np.maximum(true_rem, np.abs((T - poly) @ Ys["second"]))
        bound = Tr @ (np.abs(Y0) + np.abs(Yl).sum(0) + np.abs(Yq).sum(0))
        size = loop.r * (loop.r + 1) // 2
        wrap = max(float(bound[s * size:(s + 1) * size].sum() / max(true_rem[s * size:(s + 1) * size].sum(), 1e-300))
                   for s in range(S))
        with precision(64):
            ok = certify_second_order(loop, form, 0.05)
        rows.append((f"certificate_{ks}_{kf}", " ".join(f"{k} {x:.2e}" for k, x in worst.items())
                     + f" wrap {wrap:.1f} proved {ok}"))
    return rows


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=4)
    p.add_argument("--m", type=int, default=3)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--f", type=float, default=1e-3)
    p.add_argument("--samples", type=int, default=2000)
    p.add_argument("--box-cap", type=int, default=0, help="also box_verdict with at most this many sub-boxes")
    p.add_argument("--clock", type=float, nargs="*", default=[], help="distances below the crossing for the clock")
    p.add_argument("--pieces", type=int, default=2)
    p.add_argument("--certificates", nargs="*", default=[], metavar="KS:KF",
                   help="certificate rows: steep rates at 2^-KS, flat at 2^-KF of their range")
    p.add_argument("--out", default="/tmp/h_max_diagnosis.csv")
    args = p.parse_args()
    loop = the_loop(args.n, args.m, args.seed)
    chain = loop.chain
    a = bracket_crossing(loop)
    h = a * (1 - args.f)
    rows: list[tuple[str, str]] = [("crossing", f"{a:.9g}"), ("h", f"{h:.9g}")]
    rho, v = worst_vertex(loop, h, list(rate_points(chain)))
    v = np.asarray(v, dtype=float)
    rows += [("vertex", chain.rate_text(v)), ("vertex_rho", f"{rho:.7f}"), ("margin", f"{1 - rho:.3e}")]
    full = chain.rate_max - chain.rate_min
    free = [(idx, c) for idx, c in generator_coefficients(chain)[1] if full[idx] > 0]
    inward = {idx: (-1.0 if v[idx] == chain.rate_max[idx] else 1.0) for idx, _ in free}
    into = np.zeros_like(v)
    for idx, sign in inward.items():
        into[idx] = sign
    rng = np.random.default_rng(args.seed)
    best = rho
    for k in range(args.samples):  # half uniform over the box, half within 30 % of the vertex
        u = rng.uniform(size=v.shape)
        best = max(best, spectral_radius(loop, h, chain.rate_min + u * full if k % 2 else v + 0.3 * u * into * full))
    rows.append(("sampled_max", f"{best:.7f}"))
    for idx, _ in free:
        x = v.copy()
        x[idx] += inward[idx] * 1e-4
        rows.append((f"slope_{idx}", f"{(spectral_radius(loop, h, x) - rho) / 1e-4:.3e}"))
        x[idx] = v[idx] + inward[idx] * full[idx]
        rows.append((f"drop_{idx}", f"{spectral_radius(loop, h, x) - rho:.3e}"))
    flat = [idx for idx, _ in free if abs(float(dict(rows)[f"drop_{idx}"])) < 1 - rho]
    rows.append(("flat_rates", " ".join(map(str, flat))))
    with precision(64):
        parts = sp.MapParts.build(loop, h)
    for k in (3, 4, 5):
        lo, hi = v.copy(), v.copy()
        for idx, _ in free:
            other = v[idx] + inward[idx] * 2.0 ** -k * full[idx]
            lo[idx], hi[idx] = min(v[idx], other), max(v[idx], other)
        t = time.process_time()
        with precision(64):
            ok = sp.envelope_stable(loop, parts, lo, hi) or bool(affine_stable(loop, parts, lo, hi))
        rows.append((f"vertex_box_{k}", f"{ok} ({time.process_time() - t:.2f} CPU s)"))
    rows += flat_boxes(loop, parts, v, inward, flat)
    vd = loop.d * (loop.d + 1) // 2
    for k in (0, 1, 2, 3, 4):
        lo, hi = v.copy(), v.copy()
        for idx in flat:
            other = v[idx] + inward[idx] * 2.0 ** -k * full[idx]
            lo[idx], hi[idx] = min(v[idx], other), max(v[idx], other)
        Q = midpoint(envelope_generator(chain, lo, hi, loop.literals))
        T = assemble_map(loop, scipy.linalg.expm((loop.modes_part + np.kron(Q.T, np.eye(vd))) * h), h)
        rows.append((f"envelope_flat_{k}", f"{float(np.max(np.abs(np.linalg.eigvals(T)))):.5f}"))
    rows += certificates(loop, h, parts, v, inward, flat, [tuple(map(int, x.split(":"))) for x in args.certificates])
    rows += [(f"ordering_{k}", f"{val:.3e}") for k, val in ordering(loop, h, v, free).items()]
    if args.box_cap:
        t = time.process_time()
        verdict = sp.box_verdict(loop, h, max_boxes=args.box_cap, max_seconds=math.inf)
        rows.append(("box_verdict", f"{verdict.verdict} after {verdict.boxes} sub-boxes "
                                    f"({time.process_time() - t:.1f} CPU s): {verdict.detail}"))
    for f in args.clock:
        t = time.process_time()
        cert = clock_stable(loop, a * (1 - f), args.pieces, quadratic=True)
        rows.append((f"clock_{f:g}", f"{cert is not None and cert.proved} ({time.process_time() - t:.2f} CPU s)"))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    with open(args.out, "w", newline="") as f:
        csv.writer(f).writerows([("quantity", "value"), *rows])
    for name, value in rows:
        print(f"{name:24s} {value}")


if __name__ == "__main__":
    main()
