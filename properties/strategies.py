r"""Hypothesis strategies: small, well-scaled FTC plants and closed loops.

Every option is keyword-only and accepts either a plain value or a strategy for it.

Drawn plants (``n <= 3`` states, ``m <= 3`` modes, so every LMI solve stays ~0.1 s):

* the modes are perturbations of a common nominal plant, as faults are in FTC:
  :math:`A_i = A_0 + s U_i`, :math:`B_i = B_0 \operatorname{diag}(e_i) + s V_i`,
  :math:`C_i = C_0 + s W_i`, :math:`D_i = D_0 + s Z_i`, perturbations in ``[-1, 1]``,
  spread :math:`s \in [0, 0.5]`, actuator effectiveness :math:`e_i \in [0.3, 1]`;
* :math:`A_0 = R - 0.2 I` with ``R`` in ``[-1.3, 1.3]`` (the shift keeps the simple
  values hypothesis favours, such as ``A_0 = 0``, stabilizable);
  :math:`B_0 = U \operatorname{diag}(\sigma)` with orthonormal columns ``U`` and
  :math:`\sigma \in [0.5, 1.5]` (full column rank, ``nu <= n``);
  :math:`C_0 = R_C + 0.5 E`, :math:`D_0 = R_D + 0.5 E` with ``R`` in ``[-1, 1]`` and
  ``E`` the rectangular identity, so the disturbance-to-output map does not vanish
  (a vanishing one has :math:`\gamma_{\inf} = 0`, which ``hinf_gamma`` cannot certify);
  so every entry of every mode lies in ``[-2, 2]``;
* fault rates ``alpha[i][k]`` and detection rates ``beta_min[j][i]`` in ``[0.2, 3]``,
  ``beta_max = beta_min + width`` with width in ``[0, 2]`` (``0`` when degenerate);
* uncertainty weights (optional) ``A1, A2`` (``n x n``), ``B1`` (``n x nu``), ``B2``
  (``nu x nu``) with entries in ``[-0.3, 0.3]``, or exact zero matrices.

Gains: per FDI mode ``j`` the LQR gain :math:`K_j = -B_j^T X_j` of :math:`(A_j, B_j)`
(``Q = I``, ``R = I``, :func:`scipy.linalg.solve_continuous_are`), optionally multiplied by
a drawn factor. With the defaults most drawn loops are mean-square stable with margin
0.05 (see the hypothesis statistics: ``pytest properties --hypothesis-show-statistics``).
"""

from __future__ import annotations

import functools
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np
import scipy.linalg
from hypothesis import assume
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from numpy.typing import NDArray

from ftc_verify.closedloop import ClosedLoop, state_feedback_loop
from ftc_verify.model import FTCSystem
from ftc_verify.stability import MSSResult, mean_square_stability

__all__ = [
    "DrawnLoop",
    "matrices",
    "ftc_systems",
    "lqr_gains",
    "closed_loops",
    "stable_loops",
    "unstable_loops",
    "similarity_transforms",
    "MODE_KEYS",
]

Matrix = NDArray[np.float64]
T = TypeVar("T")
Opt = T | st.SearchStrategy[T]

MODE_KEYS = ("A", "B", "C", "D", "A1", "A2", "B1", "B2")

#: Bounds of the drawn data (see the module docstring).
A_BOUND, A_SHIFT = 1.3, 0.2
B_SINGULAR = (0.5, 1.5)
CD_BOUND, CD_FLOOR = 1.0, 0.5
#: Largest accepted gain entry. Nearly uncontrollable draws (e.g. an unstable mode reached
#: through a 1e-8 coupling) give LQR gains ~1e8 and Lyapunov matrices with condition
#: ~1e17, which no certificate (``cond(P) <= 1e8``) can accept: not "well-scaled".
GAIN_BOUND = 100.0
RATE_RANGE = (0.2, 3.0)
WIDTH_MAX = 2.0
WEIGHT_BOUND = 0.3


def _strategy(value: Opt[T]) -> st.SearchStrategy[T]:
    """``value`` itself if it is a strategy, else ``st.just(value)``."""
    return value if isinstance(value, st.SearchStrategy) else st.just(value)


def matrices(rows: int, cols: int, *, bound: float) -> st.SearchStrategy[Matrix]:
    """``rows x cols`` float matrices with entries in ``[-bound, bound]`` (no NaN/inf)."""
    return arrays(
        np.float64,
        (rows, cols),
        elements=st.floats(-bound, bound, allow_nan=False, allow_infinity=False, width=64),
    )


def _rates(m: int, *, low: float, high: float) -> st.SearchStrategy[Matrix]:
    """``m x m`` matrices of rates in ``[low, high]`` (the diagonal is set by the caller)."""
    return arrays(np.float64, (m, m), elements=st.floats(low, high, allow_nan=False, allow_infinity=False))


def _plain(value: Any) -> Any:
    """Nested lists of Python floats (exact ``repr``) for a reproducible ``repr``."""
    return np.asarray(value, dtype=float).tolist()


@dataclass(frozen=True, eq=False)
class DrawnLoop:
    """An FTC plant with one state-feedback gain per FDI mode; the loop is built lazily.

    Its ``repr`` is a ``DrawnLoop.from_spec(...)`` call with every number in full
    precision, so a falsifying example printed by hypothesis can be pasted back.
    """

    system: FTCSystem
    gains: tuple[Matrix, ...]

    @classmethod
    def from_spec(
        cls,
        *,
        modes: Sequence[Mapping[str, Any]],
        alpha: Any,
        beta_min: Any,
        beta_max: Any,
        gains: Sequence[Any],
        fault_during_delay: bool = False,
        name: str = "drawn",
    ) -> "DrawnLoop":
        """Build from plain arrays (the inverse of :meth:`spec`)."""
        system = FTCSystem.from_arrays(
            name=name,
            modes=modes,
            alpha=alpha,
            beta_min=beta_min,
            beta_max=beta_max,
            fault_during_delay=fault_during_delay,
        )
        return cls(system, tuple(np.array(K, dtype=float) for K in gains))

    def spec(self) -> dict[str, Any]:
        """Plain arrays: keyword arguments of :meth:`from_spec` (numpy arrays, copies)."""
        chain = self.system.chain
        return {
            "modes": [
                {k: np.array(getattr(md, k)) for k in MODE_KEYS if getattr(md, k) is not None}
                for md in self.system.modes
            ],
            "alpha": np.array(chain.alpha),
            "beta_min": np.array(chain.beta_min),
            "beta_max": np.array(chain.beta_max),
            "gains": [np.array(K) for K in self.gains],
            "fault_during_delay": chain.fault_during_delay,
            "name": self.system.name,
        }

    @functools.cached_property
    def loop(self) -> ClosedLoop:
        """The closed loop under ``u = K[l_t] x``."""
        return state_feedback_loop(self.system, self.gains)

    @functools.cached_property
    def mss(self) -> MSSResult:
        """Exact mean-square stability (worst spectral abscissa over the beta vertices)."""
        return mean_square_stability(self.loop)

    def _repr_pretty_(self, printer: Any, cycle: bool) -> None:
        """Hypothesis's pretty printer prints the pasteable ``repr``."""
        printer.text(repr(self))

    def __repr__(self) -> str:
        s = self.spec()
        modes = [{k: _plain(v) for k, v in md.items()} for md in s["modes"]]
        return (
            f"DrawnLoop.from_spec(modes={modes!r}, alpha={_plain(s['alpha'])!r}, "
            f"beta_min={_plain(s['beta_min'])!r}, beta_max={_plain(s['beta_max'])!r}, "
            f"gains={[_plain(K) for K in s['gains']]!r}, "
            f"fault_during_delay={s['fault_during_delay']!r})"
        )


@st.composite
def ftc_systems(
    draw: st.DrawFn,
    *,
    n: Opt[int] = st.integers(1, 3),
    m: Opt[int] = st.integers(2, 3),
    nu: Opt[int] = st.integers(1, 2),  # capped at n
    ny: Opt[int] = st.integers(1, 2),
    nw: Opt[int] = st.integers(1, 2),
    uncertain: Opt[bool] = st.booleans(),
    zero_weights: Opt[bool] = False,
    degenerate_beta: Opt[bool] = False,
    fault_during_delay: Opt[bool] = False,
    spread: Opt[float] = st.floats(0.0, 0.5),
) -> FTCSystem:
    """A well-scaled random :class:`FTCSystem` (module docstring for the distribution).

    ``degenerate_beta=True`` draws ``beta_min == beta_max``; ``zero_weights=True`` (with
    ``uncertain``) makes every uncertainty weight an exact zero matrix.
    """
    n_, m_, nu_, ny_, nw_ = (draw(_strategy(v)) for v in (n, m, nu, ny, nw))
    unc, zero, degen = draw(_strategy(uncertain)), draw(_strategy(zero_weights)), draw(_strategy(degenerate_beta))
    delay_variant = draw(_strategy(fault_during_delay))
    s = draw(_strategy(spread))
    nu_ = min(nu_, n_)
    A0 = draw(matrices(n_, n_, bound=A_BOUND)) - A_SHIFT * np.eye(n_)
    U, _ = np.linalg.qr(draw(matrices(n_, nu_, bound=1.0)))  # orthonormal columns, whatever is drawn
    B0 = U[:, :nu_] * draw(arrays(np.float64, (nu_,), elements=st.floats(*B_SINGULAR)))
    C0 = draw(matrices(ny_, n_, bound=CD_BOUND)) + CD_FLOOR * np.eye(ny_, n_)
    D0 = draw(matrices(n_, nw_, bound=CD_BOUND)) + CD_FLOOR * np.eye(n_, nw_)
    modes = []
    for _ in range(m_):
        eff = draw(arrays(np.float64, (nu_,), elements=st.floats(0.3, 1.0)))
        mode: dict[str, Matrix] = {
            "A": A0 + s * draw(matrices(n_, n_, bound=1.0)),
            "B": B0 * eff + s * draw(matrices(n_, nu_, bound=1.0)),
            "C": C0 + s * draw(matrices(ny_, n_, bound=1.0)),
            "D": D0 + s * draw(matrices(n_, nw_, bound=1.0)),
        }
        if unc:
            shapes = {"A1": (n_, n_), "A2": (n_, n_), "B1": (n_, nu_), "B2": (nu_, nu_)}
            for key, (r, c) in shapes.items():
                mode[key] = np.zeros((r, c)) if zero else draw(matrices(r, c, bound=WEIGHT_BOUND))
        modes.append(mode)
    off = ~np.eye(m_, dtype=bool)
    alpha = np.where(off, draw(_rates(m_, low=RATE_RANGE[0], high=RATE_RANGE[1])), 0.0)
    alpha -= np.diag(alpha.sum(axis=1))
    beta_min = np.where(off, draw(_rates(m_, low=RATE_RANGE[0], high=RATE_RANGE[1])), 0.0)
    width = np.zeros((m_, m_)) if degen else np.where(off, draw(_rates(m_, low=0.0, high=WIDTH_MAX)), 0.0)
    return FTCSystem.from_arrays(
        name="drawn",
        modes=modes,
        alpha=alpha,
        beta_min=beta_min,
        beta_max=beta_min + width,
        fault_during_delay=delay_variant,
    )


def lqr_gains(system: FTCSystem) -> tuple[Matrix, ...] | None:
    """Per FDI mode ``j`` the LQR gain of ``(A_j, B_j)`` (``Q = I``, ``R = I``), or
    ``None`` when some pair is not stabilizable (the Riccati solver fails), or a gain is
    not finite, not stabilizing, or has an entry above :data:`GAIN_BOUND`."""
    gains = []
    for md in system.modes:
        n, nu = md.B.shape
        try:
            # degenerate draws (rejected below) make the Riccati solver overflow: silence it
            with warnings.catch_warnings(), np.errstate(all="ignore"):
                warnings.simplefilter("ignore")
                X = scipy.linalg.solve_continuous_are(md.A, md.B, np.eye(n), np.eye(nu))
        except (np.linalg.LinAlgError, ValueError):
            return None
        K = -md.B.T @ X
        if not np.all(np.isfinite(K)) or np.max(np.abs(K)) > GAIN_BOUND:
            return None
        if np.max(np.linalg.eigvals(md.A + md.B @ K).real) >= 0:
            return None
        gains.append(K)
    return tuple(gains)


@st.composite
def closed_loops(
    draw: st.DrawFn,
    *,
    systems: st.SearchStrategy[FTCSystem] | None = None,
    gain_scale: Opt[float] = 1.0,
    **system_options: Any,
) -> DrawnLoop:
    """A plant from ``systems`` (default ``ftc_systems(**system_options)``) with its LQR
    gains times ``gain_scale``; draws whose Riccati equations fail are rejected."""
    if systems is None:
        systems = ftc_systems(**system_options)
    elif system_options:
        raise TypeError("closed_loops: give either systems or system options, not both")
    system = draw(systems)
    gains = lqr_gains(system)
    assume(gains is not None)
    assert gains is not None
    scale = draw(_strategy(gain_scale))
    return DrawnLoop(system, tuple(scale * K for K in gains))


@st.composite
def stable_loops(draw: st.DrawFn, *, margin: float = 0.05, gain_scale: Opt[float] = 1.0, **system_options: Any) -> DrawnLoop:
    """Loops mean-square stable with margin: worst spectral abscissa over the beta
    vertices ``< -margin`` (about 85 % of the LQR draws qualify)."""
    drawn = draw(closed_loops(gain_scale=gain_scale, **system_options))
    assume(drawn.mss.spectral_abscissa < -margin)
    return drawn


@st.composite
def unstable_loops(
    draw: st.DrawFn, *, margin: float = 0.05, gain_scale: Opt[float] = st.floats(-2.0, 0.0), **system_options: Any
) -> DrawnLoop:
    """Loops mean-square unstable with margin: worst spectral abscissa over the beta
    vertices ``> margin``. The LQR gains are removed or reversed (``gain_scale`` in
    ``[-2, 0]``) so that most draws qualify."""
    drawn = draw(closed_loops(gain_scale=gain_scale, **system_options))
    assume(drawn.mss.spectral_abscissa > margin)
    return drawn


@st.composite
def similarity_transforms(draw: st.DrawFn, n: int, *, max_condition: float = 10.0) -> Matrix:
    r"""Invertible ``n x n`` matrices :math:`T = Q_1 \operatorname{diag}(\sigma) Q_2` with
    orthogonal :math:`Q_1, Q_2` (QR factors of drawn matrices, always orthogonal) and
    singular values :math:`\sigma \in [1, \text{max\_condition}]`, so
    :math:`\operatorname{cond}(T) \le` ``max_condition`` by construction."""
    q1, _ = np.linalg.qr(draw(matrices(n, n, bound=1.0)))
    q2, _ = np.linalg.qr(draw(matrices(n, n, bound=1.0)))
    sigma = draw(arrays(np.float64, (n,), elements=st.floats(1.0, max_condition)))
    return q1 @ np.diag(sigma) @ q2
