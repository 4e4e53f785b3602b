"""The tilted path sampler's per-state tables (``risk.importance._JumpTable``) give the
numbers of the per-jump computation they replaced, bit for bit.

:func:`per_jump` below is the loop of :func:`ftc_verify.risk.importance.sample_tilted` as it
was before the tables (every jump: ``searchsorted`` on the state's cumulative
probabilities, ``log Q - log Q'`` and the key shares computed again). Both consume the
same draws of each path's own stream, so the paths, the log-weights and the
cross-entropy statistics must be equal exactly (``==``, no tolerance): on a chain with
Erlang delays and false alarms (many keys, jumps through several keys), on the closed-form
loop of ``tests/test_risk.py``, and from a joint state other than the first. Fixed seeds,
no statistics.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ftc_verify.model.files import load_system
from ftc_verify.model.system import JointChain
from ftc_verify.risk.importance import RateKeys, rate_keys, sample_tilted
from ftc_verify.simulation.spec import path_streams

ROOT = Path(__file__).resolve().parents[1]


def per_jump(chain: JointChain, keys: RateKeys, tilt: np.ndarray, horizon: float, seed: int, first: int, stop: int,
             start: int) -> tuple[list[tuple[np.ndarray, list[int]]], np.ndarray, np.ndarray, np.ndarray]:
    """The former loop: ``(paths as (times, joint states), log W, jumps, exposure)``."""
    q = keys.a.sum(axis=0)
    qt = keys.generator(tilt)
    exit_q, exit_t = q.sum(axis=1), qt.sum(axis=1)
    out_a = keys.a.sum(axis=2).T
    streams = path_streams(seed, first, stop)
    R = len(keys.labels)
    logw, jumps, expo = np.zeros(len(streams)), np.zeros((len(streams), R)), np.zeros((len(streams), R))
    paths = []
    for p, stream in enumerate(streams):
        gen = np.random.default_rng(stream)
        s, t = start, 0.0
        times, states = [0.0], [start]
        while True:
            rate = exit_t[s]
            dt = gen.standard_exponential() / rate if rate > 0 else np.inf
            stay = min(dt, horizon - t)
            logw[p] -= (exit_q[s] - exit_t[s]) * stay
            expo[p] += out_a[s] * stay
            if t + dt >= horizon:
                break
            t += dt
            nxt = int(np.searchsorted(np.cumsum(qt[s]) / rate, gen.random(), side="right"))
            nxt = min(nxt, qt.shape[0] - 1)
            while qt[s, nxt] <= 0.0:
                nxt -= 1
            logw[p] += np.log(q[s, nxt]) - np.log(qt[s, nxt])
            jumps[p] += tilt * keys.a[:, s, nxt] / qt[s, nxt]
            s = nxt
            times.append(t)
            states.append(s)
        paths.append((np.array(times), states))
    return paths, logw, jumps, expo


@pytest.mark.parametrize(("example", "horizon", "start"), [
    ("paper_phase_type.toml", 5.0, 0),
    ("paper_phase_type.toml", 5.0, 1),
    ("envelope_delay.toml", 10.0, 0),
])
def test_tables_give_the_per_jump_numbers_bit_for_bit(example: str, horizon: float, start: int) -> None:
    chain = load_system(ROOT / "examples" / example).chain
    beta = chain.midpoint()
    keys = rate_keys(chain, beta)
    for tilt in (np.ones(len(keys.labels)), np.linspace(0.4, 2.5, len(keys.labels))):
        got = sample_tilted(chain, keys, tilt, beta, horizon, 12, 3, 303, start)
        paths, logw, jumps, expo = per_jump(chain, keys, tilt, horizon, 12, 3, 303, start)
        assert np.array_equal(got.log_weight, logw)
        assert np.array_equal(got.jumps, jumps) and np.array_equal(got.exposure, expo)
        true_of, fdi_of = (np.array(v) for v in zip(*chain.joint_modes))
        jumped = 0
        for path, (times, states) in zip(got.paths, paths):
            keep = np.ones(times.size, dtype=bool)  # consecutive equal (true, fdi) merged, as sample_tilted does
            keep[1:] = (true_of[states][1:] != true_of[states][:-1]) | (fdi_of[states][1:] != fdi_of[states][:-1])
            assert np.array_equal(path.times, times[keep])
            assert np.array_equal(path.true, true_of[states][keep]) and np.array_equal(path.fdi, fdi_of[states][keep])
            jumped += len(states) > 1
        assert jumped > 0  # the paths jump: the tables were used
