#!/usr/bin/env python
"""CPU time of the tilted path sampler (``ftc_verify.risk.importance.sample_tilted``).

Run from the repository root (``PYTHONPATH=<checkout>`` to time another checkout's
sampler, side by side)::

    OPENBLAS_NUM_THREADS=1 python benchmarks/risk_sampling.py --out /tmp/risk_sampling.csv

For three chains (the closed-form loop of ``tests/test_risk.py``, the paper's example,
the phase-type chain with false alarms), two tilts (none, and a spread of factors) and
two start states: the process CPU seconds of drawing ``--paths`` paths, the jumps drawn,
and a digest (SHA-256 of the log-weights, jump counts, exposures and path arrays) that
must be the same for every checkout whose sampler draws the same numbers. Writes a CSV
(``--out``) and prints it.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import sys
import time
from pathlib import Path

import numpy as np

from ftc_verify.model.files import load_system
from ftc_verify.risk.importance import rate_keys, sample_tilted
from csvout import write_rows

ROOT = Path(__file__).resolve().parents[1]
CASES = (("envelope_delay.toml", 10.0, 11), ("paper.toml", 4.0, 3), ("paper_phase_type.toml", 5.0, 12))
FIELDS = ["example", "tilt", "start", "paths", "jumps", "cpu_seconds", "digest"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=3000)
    ap.add_argument("--out", default="/tmp/risk_sampling.csv")
    args = ap.parse_args()
    rows = []
    for example, horizon, seed in CASES:
        chain = load_system(ROOT / "examples" / example).chain
        beta = chain.midpoint()
        keys = rate_keys(chain, beta)
        for tilt_name, tilt in (("none", np.ones(len(keys.labels))),
                                ("spread", np.linspace(0.4, 2.5, len(keys.labels)))):
            for start in (0, 1):
                c0 = time.process_time()
                s = sample_tilted(chain, keys, tilt, beta, horizon, seed, 0, args.paths, start)
                cpu = time.process_time() - c0
                digest = hashlib.sha256()
                for a in (s.log_weight, s.jumps, s.exposure):
                    digest.update(np.ascontiguousarray(a).tobytes())
                for p in s.paths:
                    for a in (p.times, p.true, p.fdi):
                        digest.update(np.ascontiguousarray(a).tobytes())
                rows.append({"example": example, "tilt": tilt_name, "start": start, "paths": args.paths,
                             "jumps": sum(p.times.size - 1 for p in s.paths), "cpu_seconds": round(cpu, 4),
                             "digest": digest.hexdigest()[:16]})
    write_rows(args.out, rows, FIELDS)
    csv.DictWriter(sys.stdout, fieldnames=FIELDS).writerows(rows)
    print(f"total cpu_seconds {sum(r['cpu_seconds'] for r in rows):.3f}")


if __name__ == "__main__":
    main()
