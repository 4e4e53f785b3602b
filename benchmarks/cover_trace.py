#!/usr/bin/env python
"""The ``h_max`` refinement's rungs one by one (issue 31, item 2): runs
``sampled_cover.cover_h_max`` on a held-out loop of ``h_max_heldout.draw`` (conditioned
and at the analysed period 0.01, as ``refine_result`` runs it) from the default bracket's
ends ``HM``, ``HU`` (``h_max_heldout.py`` prints them) and prints, per rung, the
distance, the pieces found for its probe, the cover's sub-boxes (or FAIL), units, cubic
programs, map proofs and CPU seconds; one CSV row per rung.

    python benchmarks/cover_trace.py SEED HM HU WORK [--out FILE.csv]
    python benchmarks/cover_trace.py 13 0.49787280078105994 0.6022096970393988 3000000
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from typing import Any

from csvout import write_rows
from h_max_heldout import draw

from ftc_verify.analysis.moments import sampled_cover
from ftc_verify.analysis.moments.sampled import SampledLoop
from ftc_verify.analysis.moments.sampled_conditioned import conditioned


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("seed", type=int)
    parser.add_argument("hm", type=float)
    parser.add_argument("hu", type=float)
    parser.add_argument("work", type=float)
    parser.add_argument("--out", default=None)
    args = parser.parse_args()
    system, controller = draw(4, 3, args.seed)
    loop = conditioned(dataclasses.replace(SampledLoop.build(system, controller), written=(0.01,)))
    rows: list[dict[str, Any]] = []
    found: list[Any] = [None]
    cover, pieces = sampled_cover.cover_box, sampled_cover.rung_pieces

    def probe(*a: Any) -> Any:
        found[0] = pieces(*a)
        return found[0]

    def rung(loop_: SampledLoop, h: float, use: Any, boxes: Any, budget: float, *rest: Any) -> Any:
        t = time.process_time()
        out = cover(loop_, h, use, boxes, budget, *rest)
        row = {"seed": args.seed, "f": f"{1 - h / args.hu:.4g}", "probe_pieces": found[0] and found[0][0],
               "pieces": use, "from_boxes": len(boxes), "budget": round(budget),
               "leaves": "FAIL" if out[0] is None else len(out[0]), "units": round(out[1]), "cubic": out[2],
               "maps": out[3], "cpu_s": round(time.process_time() - t, 1)}
        found[0] = None
        rows.append(row)
        print(" ".join(f"{k} {v}" for k, v in row.items()), flush=True)
        return out

    sampled_cover.cover_box, sampled_cover.rung_pieces = rung, probe  # type: ignore[assignment]
    t0 = time.process_time()
    res = sampled_cover.cover_h_max(loop, args.hm, args.hu, args.work, 1e-3)
    gap = None if res.h_max is None else (args.hu - res.h_max) / args.hu
    print(f"seed {args.seed} work {args.work:g}: h_max {res.h_max} relative gap {gap} units {res.work:.0f} "
          f"cubic {res.attempts} maps {res.maps} {time.process_time() - t0:.0f} CPU s", flush=True)
    if args.out:
        write_rows(args.out, rows)


if __name__ == "__main__":
    main()
