r"""Importance sampling of the joint chain: tilted paths with their exact likelihood ratio,
and the cross-entropy choice of the tilt.

The randomness of a risk run is only the joint (fault, FDI, phase) chain
(:class:`~ftc_verify.model.chain.JointChain`): ``x0``, the disturbance and the rate array
are fixed. Let :math:`Q` be its generator at the rate array (:meth:`JointChain.generator`)
and write each off-diagonal entry as the sum of its terms
:math:`Q_{st} = \sum_{r} a_{r}` over the *rate keys* :math:`r` of
:meth:`JointChain.generator_terms` (a fault rate :math:`\alpha_{ik}`, a detection rate
:math:`\beta_{ji}`, a false-alarm rate). A *tilt* multiplies every term of key :math:`r`
by :math:`c_r > 0`, giving the generator :math:`Q'` with entries :math:`Q'_{st} = \sum_r
c_r a_r` and exit rates :math:`q'_s = \sum_{t \ne s} Q'_{st}`.

Likelihood ratio
----------------
A path on :math:`[0, T]` that visits :math:`s_0, s_1, \dots, s_J` with jump times
:math:`\tau_1 < \dots < \tau_J` (:math:`\tau_0 = 0`, :math:`\tau_{J+1} = T`) has density
:math:`\prod_{k=1}^{J} Q_{s_{k-1}s_k} \exp(-\sum_{k=0}^{J} q_{s_k}(\tau_{k+1} - \tau_k))`
under :math:`Q` (the last sojourn contributes its survival probability), so the
Radon--Nikodym derivative of the law of the path under :math:`Q` with respect to
:math:`Q'` is exactly

.. math::

    W = \prod_{k=1}^{J} \frac{Q_{s_{k-1}s_k}}{Q'_{s_{k-1}s_k}}
        \exp\Bigl(-\sum_{k=0}^{J} (q_{s_k} - q'_{s_k})(\tau_{k+1} - \tau_k)\Bigr),

and :math:`E_{Q'}[W\,1\{\text{leave}\}] = P_Q(\text{leave})` for any tilt with
:math:`c_r > 0` (the supports agree). Computed in logarithms.

Cross-entropy update
--------------------
For the family of tilts above, the cross-entropy program
:math:`\max_c E[W\,1\{S \ge \gamma\} \log f_{c}(\text{path})]` has the closed-form solution

.. math::

    c_r = \frac{\sum_p W_p 1_p N_{r,p}}{\sum_p W_p 1_p \int_0^T a_r(s_p(t))\,dt},

where :math:`N_{r,p}` counts the jumps of path :math:`p` through key :math:`r` (a jump
whose entry has several keys counts each by its share :math:`c_r a_r / Q'_{st}`) and
:math:`a_r(s)` is the untilted rate of key :math:`r` out of state :math:`s` (0 if none).
The elite level :math:`\gamma` rises over the iterations towards the envelope (adaptive
multilevel cross-entropy, Rubinstein and Kroese, *The Cross-Entropy Method*, 2004, ch. 3).

Randomness: path ``k`` draws from ``numpy.random.default_rng(stream_k)``, ``stream_k`` the
``k``-th child stream of :func:`~ftc_verify.simulation.spec.path_streams`, carried as
:attr:`ChainPath.stream <ftc_verify.simulation.paths.ChainPath>` (so a random ``Delta``
is drawn from the path's own stream as in every simulator).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np

from ..model.system import JointChain, Matrix
from ..simulation.paths import ChainPath
from ..simulation.spec import path_streams

__all__ = ["RateKeys", "TiltedPaths", "rate_keys", "sample_tilted", "cross_entropy_tilt"]

#: Bounds of a tilt factor (keeps every tilted rate positive and finite).
TILT_MIN, TILT_MAX = 1e-3, 1e3


@dataclass(frozen=True, eq=False)
class RateKeys:
    """The rate keys of a chain at one rate array.

    ``labels[r]``: e.g. ``alpha[1,2]`` (1-based); ``a[r]``: ``(N, N)`` the untilted rate
    of key ``r`` from ``s`` to ``t`` (``Q = sum_r a[r]`` off the diagonal)."""

    labels: tuple[str, ...]
    a: np.ndarray

    def generator(self, tilt: np.ndarray) -> np.ndarray:
        """Off-diagonal tilted rates :math:`Q'_{st}` (zero diagonal)."""
        return np.einsum("r,rst->st", tilt, self.a)


def _label(kind: str, index: tuple[int, ...], false_alarms: bool) -> str:
    if kind == "alpha":
        return f"alpha[{index[0] + 1},{index[1] + 1}]"
    name = "beta" if not false_alarms or index[0] == 0 else "false_alarm"
    i, j = index[-2:]
    return f"{name}[{i + 1},{j + 1}]"


def rate_keys(chain: JointChain, beta: Matrix) -> RateKeys:
    """The keys of :meth:`JointChain.generator_terms` at rate array ``beta`` (zero rates
    dropped: a tilt cannot make them positive)."""
    point = chain.check_beta(beta)
    n = chain.n_states
    keys: dict[str, np.ndarray] = {}
    for s, t, coef, kind, index in chain.generator_terms():
        value = coef * (chain.alpha[index] if kind == "alpha" else point[index])
        if value > 0:
            label = _label(kind, index, chain.has_false_alarms)
            keys.setdefault(label, np.zeros((n, n)))[s, t] += value
    labels = tuple(keys)
    return RateKeys(labels, np.stack([keys[k] for k in labels]) if labels else np.zeros((0, n, n)))


@dataclass(frozen=True, eq=False)
class TiltedPaths:
    """Paths drawn under a tilt: ``paths`` for the simulators, ``log_weight`` (``(P,)``,
    :math:`\\log W`), and the cross-entropy statistics ``jumps`` (``(P, R)``: jumps per
    key) and ``exposure`` (``(P, R)``: :math:`\\int_0^T a_r(s(t))\\,dt`)."""

    paths: tuple[ChainPath, ...]
    log_weight: np.ndarray
    jumps: np.ndarray
    exposure: np.ndarray


def sample_tilted(chain: JointChain, keys: RateKeys, tilt: np.ndarray, beta: Matrix, horizon: float,
                  seed: int | np.random.SeedSequence, first: int, stop: int, start: int = 0) -> TiltedPaths:
    r"""Paths ``first .. stop - 1`` of the stream of ``seed`` under the tilt (module
    docstring), from joint state ``start``, each with its exact :math:`\log W`.

    Exact sampling of :math:`Q'`: holding time :math:`E/q'_s` (:math:`E` standard
    exponential), next state :math:`t` with probability :math:`Q'_{st}/q'_s`."""
    q = keys.a.sum(axis=0)
    qt = keys.generator(tilt)
    exit_q, exit_t = q.sum(axis=1), qt.sum(axis=1)
    out_a = keys.a.sum(axis=2).T  # (N, R): untilted rate of key r out of s
    true_of, fdi_of = (np.array(v, dtype=np.int64) for v in zip(*chain.joint_modes))
    streams = path_streams(seed, first, stop)
    R = len(keys.labels)
    logw, jumps, expo = np.zeros(len(streams)), np.zeros((len(streams), R)), np.zeros((len(streams), R))
    table = _JumpTable.build(keys, tilt, q, qt, exit_t)
    rates, drift = exit_t.tolist(), (exit_q - exit_t).tolist()
    out_rows = out_a.tolist()
    share_rows = [{t: v.tolist() for t, v in row.items()} for row in table.shares]
    pairs = list(zip(true_of.tolist(), fdi_of.tolist()))
    keys_r = range(R)
    paths = []
    for p, stream in enumerate(streams):
        gen = np.random.default_rng(stream)
        s, t, lw = start, 0.0, 0.0
        # the per-key sums in Python floats, added in the path's order: the same IEEE
        # double operations as the former row updates ``expo[p] += out_a[s] * stay``
        ex, ju = [0.0] * R, [0.0] * R
        times, states = [0.0], [start]
        while True:
            rate = rates[s]
            dt = gen.standard_exponential() / rate if rate > 0 else math.inf
            stay = min(dt, horizon - t)
            lw -= drift[s] * stay
            row = out_rows[s]
            for r in keys_r:
                ex[r] += row[r] * stay
            if t + dt >= horizon:
                break
            t += dt
            nxt = table.next_state(s, gen.random())
            lw += table.log_ratio[s][nxt]
            share = share_rows[s][nxt]
            for r in keys_r:
                ju[r] += share[r]
            s = nxt
            times.append(t)
            states.append(s)
        logw[p], expo[p], jumps[p] = lw, ex, ju
        paths.append(_chain_path(times, [pairs[x] for x in states], beta, horizon, stream))
    return TiltedPaths(tuple(paths), logw, jumps, expo)


@dataclass(frozen=True, eq=False)
class _JumpTable:
    """Per state ``s``: the cumulative jump probabilities ``cumsum(Q'_s.) / q'_s`` (a plain
    list, searched with :func:`bisect.bisect_right` exactly as ``numpy.searchsorted(...,
    side="right")`` searches the same numbers), and per jump ``s -> t`` with
    :math:`Q'_{st} > 0` the log-ratio term :math:`\\log Q_{st} - \\log Q'_{st}` and the
    key shares :math:`c_r a_{r,st} / Q'_{st}`: what :func:`sample_tilted` adds per jump,
    computed once per state instead of once per jump (the same floating-point numbers)."""

    cumulative: list[list[float]]
    log_ratio: list[dict[int, float]]
    shares: list[dict[int, np.ndarray]]

    @classmethod
    def build(cls, keys: RateKeys, tilt: np.ndarray, q: np.ndarray, qt: np.ndarray, exit_t: np.ndarray) -> _JumpTable:
        N = qt.shape[0]
        cumulative, log_ratio, shares = [], [], []
        for s in range(N):
            cumulative.append((np.cumsum(qt[s]) / exit_t[s]).tolist() if exit_t[s] > 0 else [])
            targets = [t for t in range(N) if qt[s, t] > 0.0]
            log_ratio.append({t: float(np.log(q[s, t]) - np.log(qt[s, t])) for t in targets})
            shares.append({t: tilt * keys.a[:, s, t] / qt[s, t] for t in targets})
        return cls(cumulative, log_ratio, shares)

    def next_state(self, s: int, u: float) -> int:
        """The state a jump from ``s`` goes to for the uniform draw ``u``."""
        row = self.cumulative[s]
        nxt = min(bisect.bisect_right(row, u), len(row) - 1)
        while nxt not in self.shares[s]:  # rounding at the top of the cumulative sum
            nxt -= 1
        return nxt


def _chain_path(times: list[float], modes: list[tuple[int, int]], beta: Matrix, horizon: float,
                stream: np.random.SeedSequence) -> ChainPath:
    """The :class:`ChainPath` of a state sequence (its jump ``times`` and ``(true, fdi)``
    per segment): consecutive equal ``(true, fdi)`` merged (a detection phase is not a
    mode switch), as :func:`~ftc_verify.simulation.paths.sample_paths` does."""
    keep = [0] + [k for k in range(1, len(modes)) if modes[k] != modes[k - 1]]
    return ChainPath(np.array([times[k] for k in keep]), np.array([modes[k][0] for k in keep], dtype=np.int64),
                     np.array([modes[k][1] for k in keep], dtype=np.int64), np.array(beta, dtype=float), horizon,
                     stream)


def cross_entropy_tilt(sample: TiltedPaths, elite: np.ndarray, previous: np.ndarray, smoothing: float = 0.7
                       ) -> np.ndarray:
    r"""The cross-entropy update of the module docstring on the ``elite`` paths (boolean
    ``(P,)``), smoothed: :math:`c \leftarrow \eta\, c_{CE} + (1 - \eta)\, c_{previous}`
    (:math:`\eta` = ``smoothing``; a key no elite path was exposed to keeps its factor),
    clipped to ``[TILT_MIN, TILT_MAX]``."""
    w = np.where(elite, np.exp(sample.log_weight - np.max(sample.log_weight[elite], initial=0.0)), 0.0)
    num = w @ sample.jumps
    den = w @ sample.exposure
    ce = np.where(den > 0, num / np.where(den > 0, den, 1.0), previous)
    return np.clip(smoothing * ce + (1.0 - smoothing) * previous, TILT_MIN, TILT_MAX)
