"""The four side measurements of ``benchmarks/results/mono13.md`` (round 13), on the
held-out ``n = 4, m = 3`` loops of ``benchmarks/mono13_signs.py`` at ``h = a (1 - f)``:

* ``edge SEED RATE``: along the edge from the worst vertex into the box in one rate
  (``RATE`` as ``i,j``), the margin ``1 - rho`` and the radius's derivative into the box,
  with the other rates at the vertex and at 1/8 into the box (``f = 1e-3``);
* ``cost``: CPU seconds of the envelope map's ball, a 378-row Van Loan ball exponential
  and a 189-row one (seed 13, ``f = 1e-3``);
* ``present SEED SPEC ...``: the present sub-box proof (``sampled_proof.subbox_stable``) on
  six random aligned cells of relative widths ``2^-k`` per rate (``x``: the rate at the
  vertex), with each cell's corner margin (``f = 1e-3``);
* ``face SEED F RATES CAP``: ``box_verdict`` on the face where the rates ``RATES``
  (``i,j;k,l``) sit at the worst vertex, with at most ``CAP`` sub-boxes.

    python benchmarks/mono13_extra.py edge 26 2,0
    python benchmarks/mono13_extra.py cost
    python benchmarks/mono13_extra.py present 13 3,x,3,x,x,3 4,x,4,x,x,4
    python benchmarks/mono13_extra.py face 31 1e-3 "0,2;1,2;2,0" 300
"""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import time

import numpy as np

from mono13_signs import Setup, perron, vertex_box

from ftc_verify.analysis.moments import sampled_proof as sp
from ftc_verify.analysis.moments.fast_balls import ball_expm
from ftc_verify.analysis.moments.sampled_balls import envelope_generator
from ftc_verify.analysis.rigorous import precision


def edge(seed: int, rate: tuple[int, ...]) -> None:
    """The ``edge`` rows (module docstring)."""
    s = Setup(seed, 1e-3)
    full = s.hi - s.lo
    coef = dict(s.free)[rate]
    for name, other in (("edge", 0.0), ("others 1/8 in", 0.125)):
        row = []
        for t in (0, 1 / 64, 1 / 16, 1 / 8, 1 / 4, 1 / 2, 3 / 4, 1):
            x = s.v.copy()
            for idx, _ in s.free:
                x[idx] += s.inward[idx] * other * full[idx]
            x[rate] = s.v[rate] + s.inward[rate] * t * full[rate]
            rho, pv, pw = perron(s.map(x))
            plus, minus = s.parts(coef)
            d = s.inward[rate] * (pw @ s.J(s.generator(x), plus - minus) @ pv)
            row.append(f"t {t:.3g}: 1-rho {1 - rho:.2e} into {d:+.1e}")
        print(seed, rate, name, " | ".join(row))


def cost() -> None:
    """The ``cost`` rows (module docstring)."""
    s = Setup(13, 1e-3)
    full = s.hi - s.lo
    lo, hi = s.v.copy(), s.v.copy()
    for idx, _ in s.free:
        o = s.v[idx] + s.inward[idx] * 0.125 * full[idx]
        lo[idx], hi[idx] = min(s.v[idx], o), max(s.v[idx], o)
    print("load", os.getloadavg()[0])
    with precision(64):
        parts = sp.MapParts.build(s.loop, s.h)
        t = time.process_time()
        for _ in range(3):
            parts.map(envelope_generator(s.loop.chain, lo, hi, s.loop.literals).value)
        print(f"envelope map ball (189 rows -> 90): {(time.process_time() - t) / 3:.3f} CPU s")
    L = s.envelope(lo, hi, True)
    plus, _ = s.parts(s.free[0][1])
    N = L.shape[0]
    M = np.block([[L, plus], [np.zeros((N, N)), L]]) * s.h
    for name, A in ((f"Van Loan ball exponential ({2 * N} rows)", M), (f"ball exponential ({N} rows)", L * s.h)):
        t = time.process_time()
        for _ in range(3):
            ball_expm((A, np.zeros_like(A)))
        print(f"{name}: {(time.process_time() - t) / 3:.3f} CPU s")


def present(seed: int, specs: list[str]) -> None:
    """The ``present`` rows (module docstring)."""
    s = Setup(seed, 1e-3)
    with precision(64):
        parts = sp.MapParts.build(s.loop, s.h)
    print("load", os.getloadavg()[0])
    rng = np.random.default_rng(7)
    for a in specs:
        spec = [np.inf if x == "x" else float(x) for x in a.split(",")]
        ok, cpu, rows = 0, 0.0, []
        for _ in range(6):
            offset = [0.0 if k == np.inf else rng.integers(0, 2 ** int(k)) * 2.0 ** -k for k in spec]
            lo, hi = vertex_box(s, spec, offset)
            corner = s.v.copy()
            for j, (idx, _) in enumerate(s.free):
                corner[idx] = s.v[idx] + s.inward[idx] * offset[j] * (s.hi[idx] - s.lo[idx])
            margin = 1 - perron(s.map(corner))[0]
            t = time.process_time()
            proved = sp.subbox_stable(s.loop, s.h, parts, lo, hi)
            cpu += time.process_time() - t
            ok += proved
            rows.append(f"{margin:.1e}:{'P' if proved else '-'}")
        print(a, f"proved {ok}/6, {cpu / 6:.2f} CPU s each |", " ".join(rows), flush=True)


def face(seed: int, f: float, rates: str, cap: int) -> None:
    """The ``face`` row (module docstring)."""
    s = Setup(seed, f)
    fixed = [tuple(int(c) for c in a.split(",")) for a in rates.split(";")] if rates else []
    ch = s.loop.chain
    bmin, bmax = np.array(ch.beta_min, float), np.array(ch.beta_max, float)
    for idx in fixed:
        bmin[idx] = bmax[idx] = s.v[idx]
    loop = dataclasses.replace(s.loop, chain=dataclasses.replace(ch, beta_min=bmin, beta_max=bmax))
    print("load", os.getloadavg()[0], "seed", seed, "f", f, "fixed", fixed, flush=True)
    t = time.process_time()
    v = sp.box_verdict(loop, s.h, max_boxes=cap, max_seconds=math.inf)
    print(v.verdict, v.boxes, "sub-boxes", f"{time.process_time() - t:.1f} CPU s", v.detail[:200], flush=True)


def main() -> None:
    mode, args = sys.argv[1], sys.argv[2:]
    if mode == "edge":
        edge(int(args[0]), tuple(int(c) for c in args[1].split(",")))
    elif mode == "cost":
        cost()
    elif mode == "present":
        present(int(args[0]), args[1:])
    elif mode == "face":
        face(int(args[0]), float(args[1]), args[2], int(args[3]))
    else:
        raise SystemExit(__doc__)


if __name__ == "__main__":
    main()
