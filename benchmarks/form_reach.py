#!/usr/bin/env python
"""Where the sub-box proofs' polynomial forms succeed, issue 31 item 2: depth first from
the whole box of a held-out ``n = 4, m = 3`` loop (``h_max_diagnosis.the_loop``,
conditioned) at ``h = HU (1 - F)``, halved by ``sampled_proof.split_rate``, each sub-box
tried by the envelope alone (``sampled_proof.envelope_stable``), then, where it fails, by
its form (``sampled_taylor.affine_stable`` with every form paid, the third-order one
included), recording the eigenpair enclosure's reach of a form that proves nothing
(``sampled_eigen.enclosure_reach``); up to ``CAP`` sub-boxes. One CSV row: sub-boxes,
proved by the envelope / by a form, failed, CPU s of the envelopes and of the forms (of
the failed ones), the largest parent reach of a sub-box a form proved, and how many
failed forms the cover's rule (``sampled_cover.REACH_MAX``, ``REACH_SHRINK``) would not
have computed.

    python benchmarks/form_reach.py SEED HU F CAP [--out FILE.csv]
    python benchmarks/form_reach.py 13 0.6022096970393988 9e-4 1000
"""

from __future__ import annotations

import time

import numpy as np

from csvout import write_rows
from h_max_diagnosis import held_out_rung, rung_parser

from ftc_verify.analysis.moments.sampled_cover import REACH_MAX, REACH_SHRINK
from ftc_verify.analysis.moments.sampled_proof import envelope_stable, split_rate
from ftc_verify.analysis.moments.sampled_taylor import FormSpend, affine_stable
from ftc_verify.analysis.rigorous import precision


def main() -> None:
    parser = rung_parser(__doc__)
    parser.add_argument("cap", type=int)
    args = parser.parse_args()
    rung = held_out_rung(args.seed, args.hu, args.f)
    loop, h, parts = rung.loop, rung.h, rung.parts
    chain = loop.chain
    # (lo, hi, the parent's reach or None, the expected reach by the cover's rule)
    stack = [(np.array(chain.rate_min, dtype=float), np.array(chain.rate_max, dtype=float), None, 0.0)]
    count = {"envelope": 0, "form": 0, "failed": 0, "skipped_failed": 0}
    cpu = {"envelope": 0.0, "form_failed": 0.0}
    parent_of_proved = 0.0
    while stack and sum(count[k] for k in ("envelope", "form", "failed")) < args.cap:
        lo, hi, parent, expected = stack.pop()
        t0 = time.process_time()
        with precision(64):
            env = envelope_stable(loop, parts, lo, hi)
        cpu["envelope"] += time.process_time() - t0
        if env:
            count["envelope"] += 1
            continue
        seen: list[float] = []
        t0 = time.process_time()
        with precision(64):
            form = bool(affine_stable(loop, parts, lo, hi, FormSpend(lambda: True, lambda: True, seen.append)))
        if form:
            count["form"] += 1
            parent_of_proved = max(parent_of_proved, parent if parent is not None else 0.0)
            continue
        cpu["form_failed"] += time.process_time() - t0
        count["failed"] += 1
        count["skipped_failed"] += expected > REACH_MAX
        own = seen[0] if seen else None
        child = REACH_SHRINK * (own if own is not None else expected)
        r = split_rate(loop, h, lo, hi)
        mid = 0.5 * (lo[r] + hi[r])
        upper, lower = lo.copy(), hi.copy()
        upper[r] = mid
        lower[r] = mid
        stack.append((lo, lower, own, child))
        stack.append((upper, hi, own, child))
    row = {"seed": args.seed, "f": args.f, "boxes": sum(count[k] for k in ("envelope", "form", "failed")),
           "envelope": count["envelope"], "form": count["form"], "failed": count["failed"],
           "cpu_envelope": round(cpu["envelope"], 1), "cpu_form_failed": round(cpu["form_failed"], 1),
           "max_parent_reach_of_proved": round(parent_of_proved, 3), "failed_not_computed_by_rule": count["skipped_failed"]}
    print(" ".join(f"{k} {v}" for k, v in row.items()), flush=True)
    if args.out:
        write_rows(args.out, [row])


if __name__ == "__main__":
    main()
