r"""Monte Carlo estimation of the expected output energy and attenuation ratio.

Given per-path energies :math:`Y_i = \int_0^T |y|^2` and :math:`W_i = \int_0^T |w|^2` from
either simulation backend (the disturbance is deterministic, so :math:`W_i` differs
between paths only through the trapezoid rule on each path's grid):

* **mean and one-sided upper bound** of :math:`\rho = E[Y]/\bar W` by the Student-t
  interval :math:`\bar Y + t_{1-\alpha, n-1} s/\sqrt{n}`, divided by :math:`\bar W`. It
  assumes i.i.d. paths with finite variance and relies on the central limit theorem;
  per-path energies are unbounded (a path may stay in a bad mode), so no
  distribution-free (Hoeffding-type) bound applies to them directly. Default
  :math:`\alpha = 10^{-6}`.
* **distribution-free companion**: the per-path event :math:`Y_i/W_i \le \gamma^2` is a
  Bernoulli trial; its probability gets an exact Clopper-Pearson interval (as statistical
  model checkers do). It concerns a quantile, not the mean.
* **sequential mode**: batches are drawn until the upper bound falls below
  :math:`\gamma^2` (decided: pass) or the lower bound rises above it (decided: fail), or
  the path budget is spent; look :math:`k` uses :math:`\alpha/2^k`, so the total false
  decision probability stays below :math:`\alpha` (Bonferroni over looks).

Every estimate records the seed of the generator that drew the paths.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.stats

from ..controllers.controller import Controller
from ..errors import ValidationError
from ..model.system import FTCSystem

if TYPE_CHECKING:
    from ..simulation.spec import SimulationSpec

__all__ = ["MCEstimate", "estimate", "clopper_pearson", "sequential_estimate", "monte_carlo"]


def clopper_pearson(successes: int, trials: int, alpha: float) -> tuple[float, float]:
    """Exact two-sided ``1 - alpha`` interval for a binomial proportion."""
    lo = 0.0 if successes == 0 else float(scipy.stats.beta.ppf(alpha / 2, successes, trials - successes + 1))
    hi = 1.0 if successes == trials else float(scipy.stats.beta.ppf(1 - alpha / 2, successes + 1, trials - successes))
    return lo, hi


@dataclass(frozen=True)
class MCEstimate:
    """Monte Carlo summary of ``E||y||^2 / ||w||^2`` (see module docstring)."""

    paths: int
    seed: int | None
    alpha: float
    mean_energy: float
    std_energy: float
    w_energy: float
    mean_ratio: float
    lower_bound: float
    upper_bound: float
    gamma: float | None
    event_fraction: float | None
    event_interval: tuple[float, float] | None
    decided: str = "fixed"  # "fixed" (no sequential test), "pass", "fail", "undecided"
    diverged: int = 0  # paths whose energy is infinite (the loop state left the divergence bound)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary."""
        return {
            "paths": self.paths,
            "seed": self.seed,
            "alpha": self.alpha,
            "method": "one-sided Student-t bound on the mean energy (CLT, finite variance)",
            "mean_energy": self.mean_energy,
            "std_energy": self.std_energy,
            "w_energy": self.w_energy,
            "mean_ratio": self.mean_ratio,
            "lower_bound": self.lower_bound,
            "upper_bound": self.upper_bound,
            "gamma": self.gamma,
            "event": None if self.event_fraction is None else {
                "definition": "ratio_i <= gamma^2",
                "fraction": self.event_fraction,
                "clopper_pearson": list(self.event_interval or ()),
            },
            "decided": self.decided,
            "diverged": self.diverged,
            "note": (f"{self.diverged} of {self.paths} paths diverged: the mean energy and its bounds are "
                     "infinite (null)") if self.diverged else None,
        }


def estimate(
    y_energy: np.ndarray,
    w_energy: np.ndarray,
    *,
    alpha: float = 1e-6,
    gamma: float | None = None,
    seed: int | None = None,
) -> MCEstimate:
    """Summarise per-path energies (module docstring); bounds are one-sided at ``alpha``
    each (the pair is a ``1 - 2 alpha`` two-sided interval). A path energy of ``inf`` (or NaN)
    is a diverged path: the mean energy and both bounds are then ``inf``, ``diverged`` counts
    such paths, and a sequential test decides ``fail``."""
    y = np.asarray(y_energy, dtype=float)
    y = np.where(np.isnan(y), np.inf, y)
    w = np.asarray(w_energy, dtype=float)
    if y.ndim != 1 or y.shape != w.shape or y.size < 2:
        raise ValidationError(f"energies: need two equal 1-D arrays with >= 2 paths, got {y.shape} and {w.shape}")
    if not (0 < alpha < 0.5):
        raise ValidationError(f"alpha: must lie in (0, 0.5), got {alpha!r}")
    if not np.all(np.isfinite(w)):
        raise ValidationError("w_energy: non-finite disturbance energy")
    n = y.size
    wbar = float(np.mean(w))
    if wbar <= 0:
        raise ValidationError(f"w_energy: the disturbance has zero energy ({wbar!r}); the ratio is undefined")
    frac = interval = None
    if gamma is not None:
        hits = int(np.sum(y <= gamma ** 2 * w))  # a diverged path (inf) is a miss
        frac, interval = hits / n, clopper_pearson(hits, n, 2 * alpha)
    diverged = int(np.sum(~np.isfinite(y)))
    if diverged:
        inf = math.inf
        return MCEstimate(n, seed, alpha, inf, inf, wbar, inf, inf, inf, gamma, frac, interval, diverged=diverged)
    mean, std = float(np.mean(y)), float(np.std(y, ddof=1))
    half = float(scipy.stats.t.ppf(1 - alpha, n - 1)) * std / math.sqrt(n)
    return MCEstimate(n, seed, alpha, mean, std, wbar, mean / wbar, (mean - half) / wbar, (mean + half) / wbar,
                      gamma, frac, interval)


def sequential_estimate(
    draw: Callable[[int], tuple[np.ndarray, np.ndarray]],
    *,
    gamma: float,
    batch: int = 200,
    max_paths: int = 5000,
    alpha: float = 1e-6,
    seed: int | None = None,
) -> MCEstimate:
    """Draw batches (``draw(k)`` returns ``k`` paths' ``(Y, W)``) until the comparison of
    the mean ratio with ``gamma**2`` is decided at level ``alpha`` (alpha-spending
    ``alpha / 2**look``) or ``max_paths`` are used."""
    ys: list[np.ndarray] = []
    ws: list[np.ndarray] = []
    look = 0
    est: MCEstimate | None = None
    while sum(len(v) for v in ys) < max_paths:
        y, w = draw(min(batch, max_paths - sum(len(v) for v in ys)))
        ys.append(np.asarray(y))
        ws.append(np.asarray(w))
        look += 1
        est = estimate(np.concatenate(ys), np.concatenate(ws), alpha=alpha / 2 ** look, gamma=gamma, seed=seed)
        if est.upper_bound < gamma ** 2:
            return _decided(est, "pass", alpha)
        if est.lower_bound > gamma ** 2:
            return _decided(est, "fail", alpha)
    assert est is not None
    return _decided(est, "undecided", alpha)


def _decided(est: MCEstimate, verdict: str, alpha: float) -> MCEstimate:
    return dataclasses.replace(est, alpha=alpha, decided=verdict)


def monte_carlo(
    system: FTCSystem,
    controller: Controller,
    *,
    backend: str = "reference",
    spec: SimulationSpec | None = None,
    paths: int | None = None,
    horizon: float | None = None,
    step: float | None = None,
    seed: int | None = None,
    gamma: float | None = None,
    alpha: float = 1e-6,
    sequential: bool = False,
    batch: int = 200,
    beta: Any = None,
    delta: Any = None,
) -> MCEstimate:
    """Estimate ``E||y||^2/||w||^2`` on ``backend`` (``"reference"`` or ``"fmu"``) with the
    run of ``spec`` (:class:`~ftc_verify.simulation.spec.SimulationSpec`: ``n_paths`` exact
    chain paths on ``[0, horizon]``, path ``k`` from stream ``k`` of ``seed``
    (:func:`~ftc_verify.simulation.spec.path_streams`), ``beta`` drawn per path unless
    given, ``delta``, sample-and-hold at ``step``, the spec's disturbance). The keywords
    ``paths`` (default 1000), ``horizon``, ``step``, ``seed``, ``beta``, ``delta`` are its
    shorthand (:func:`~ftc_verify.simulation.spec.spec_from`). ``sequential=True`` (needs
    ``gamma``) draws batches of ``batch`` paths until the comparison with ``gamma**2`` is
    decided or ``n_paths`` are used. The seed (drawn and recorded when ``None``) is in the
    result."""
    from ..simulation.spec import spec_from

    if backend not in ("reference", "fmu"):
        raise ValidationError(f"backend: must be 'reference' or 'fmu', got {backend!r}")
    if sequential and gamma is None:
        raise ValidationError("gamma: the sequential mode compares with gamma, which is missing")
    if spec is None and paths is None:
        paths = 1000
    spec = spec_from(spec, {"n_paths": paths, "horizon": horizon, "step": step, "seed": seed, "beta": beta,
                            "delta": delta}).with_seed()
    drawn = 0  # paths numbered on from batch to batch

    def draw(count: int) -> tuple[np.ndarray, np.ndarray]:
        nonlocal drawn
        chunk = spec.sample_paths(system.chain, drawn, drawn + count)
        drawn += count
        if backend == "reference":
            from ..simulation.reference import energies_reference

            return energies_reference(system, controller, chunk, spec=spec)
        from ..simulation.supervisor import simulate_fmu

        res = simulate_fmu(system, controller, chunk, spec=spec)
        return (np.array([r.y_norm ** 2 for r in res.records]), np.array([r.w_norm ** 2 for r in res.records]))

    if sequential:
        assert gamma is not None
        return sequential_estimate(draw, gamma=gamma, batch=batch, max_paths=spec.n_paths, alpha=alpha,
                                   seed=spec.seed)
    y, w = draw(spec.n_paths)
    return estimate(y, w, alpha=alpha, gamma=gamma, seed=spec.seed)
