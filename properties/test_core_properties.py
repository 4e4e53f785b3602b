r"""Property tests of the analysis core: exact stability test, Theorem 3.1, Theorem 3.2, Lemma 4.1,
and the closed loop of dynamic controllers.

Notation: joint mode :math:`s = (i, j)` (true, FDI), closed loop
:math:`A_s = A_i + B_i K_j`, generator :math:`Q(\beta)` of the joint chain, second-moment
generator :math:`\mathcal L(\beta)` whose spectral abscissa decides mean-square stability,
:math:`\gamma_{\inf}` the infimum of the :math:`\gamma` for which the LMI of Theorem 3.2
(nominal) or Lemma 4.1 (robust) is feasible over the whole :math:`\beta` box.

Tolerances on certified gammas
------------------------------
``hinf_gamma`` reports :math:`\gamma_c = \gamma^*(1+\rho) + 10^{-7}`: :math:`\gamma^*` is the
step-1 minimum from Clarabel (tolerances 1e-9 on :math:`g = \gamma^2`; for the drawn
well-scaled loops, :math:`\gamma \in [0.05, 50]` roughly, that is well below 1e-5 relative
on :math:`\gamma`) and :math:`\rho` the first rung of ``GAMMA_LADDER`` whose numpy
certificate passes (1e-4 for almost every draw, sometimes 1e-3). A certificate is a
proof in ball arithmetic (no margin), so
:math:`\gamma_{\inf} \le \gamma_c \lesssim \gamma_{\inf}(1+\rho)`: two certified values of
the same :math:`\gamma_{\inf}` agree to about 1.1e-3 relative. :data:`GAMMA_RTOL` = 5e-3
leaves a 4x headroom over that. When a result reports a rung above 1e-3 (tiny gammas,
where the certificate's margin on the :math:`-gI` block needs a larger relative slack),
its lower bound is widened by that rung: :math:`\gamma_{\inf} \ge \gamma_c / (1+\rho)`.
Gammas are compared only when both results are certified.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import assume, event, given, note
from hypothesis import strategies as st

from ftc_verify.analysis.lmi_analysis import GAMMA_LADDER, LMIResult, hinf_gamma, mes_lmi
from ftc_verify.analysis.rigorous import ball, precision, proven_positive_definite
from ftc_verify.analysis.moments.stability import second_moment_generator, spectral_abscissa
from ftc_verify.model.system import Matrix
from ftc_verify.testing import (
    DrawnLoop,
    closed_loops,
    matrices,
    similarity_transforms,
    stable_loops,
    unstable_loops,
)

from .transforms import controller_similarity, relabel, scale_disturbance, similarity, with_beta_box

#: Relative tolerance between certified gammas (module docstring).
GAMMA_RTOL = 5e-3
#: Absolute floor: the ``+1e-7`` offset of the ladder, with room.
GAMMA_ATOL = 1e-6
#: Ladder rungs already covered by GAMMA_RTOL.
COVERED_RUNG = 1e-3
#: Spectral abscissae of similar (or permuted) generators: relative tolerance for a
#: simple dominant eigenvalue, with an absolute floor relative to ``||L||_2``.
ABSCISSA_RTOL = 1e-8
ABSCISSA_ATOL_REL = 1e-10
#: Stability margin away from the boundary for the "iff" and the gamma properties.
MARGIN = 0.05
#: Exact detection rates (``beta_min == beta_max``), or widths drawn in [0, 2] half the time.
EXACT_BETA = {"beta_width": 0.0}
ANY_BETA = {"beta_width": st.sampled_from([0.0, 2.0])}

def small(**options: object) -> dict[str, object]:
    """Options of ``ftc_verify.testing.systems`` for this suite: 1 to 3 states (the public
    default is 2 to 4) and uncertainty weights drawn or not, unless ``options`` say otherwise."""
    return {"n": (1, 3), "uncertain": None, **options}


_RUNG = re.compile(r"\(\+([0-9.eE+-]+) relative\)")


# --------------------------------------------------------------------------- helpers


def ladder_rung(res: LMIResult) -> float:
    """The ``GAMMA_LADDER`` rung at which ``res`` was certified, read from its message;
    the smallest rung when the message does not say (keeps the comparison strict)."""
    found = _RUNG.search(res.message)
    return float(found.group(1)) if found else GAMMA_LADDER[0]


def gamma_interval(res: LMIResult, factor: float = 1.0) -> tuple[float, float]:
    r"""Interval that must contain :math:`\text{factor} \cdot \gamma_{\inf}` given the
    certified ``res`` (module docstring)."""
    assert res.certified and res.gamma is not None
    g = factor * res.gamma
    extra = max(0.0, ladder_rung(res) - COVERED_RUNG)
    return g / ((1.0 + extra) * (1.0 + GAMMA_RTOL)) - GAMMA_ATOL, g * (1.0 + GAMMA_RTOL) + GAMMA_ATOL


def describe(*results: LMIResult) -> str:
    """One line per result for assertion messages."""
    return "\n".join(f"{r.condition}: {r.outcome} gamma={r.gamma!r} ({r.message})" for r in results)


def assert_same_gamma(a: LMIResult, b: LMIResult, *, factor_b: float = 1.0) -> None:
    r""":math:`\gamma_{\inf}(a) = \text{factor\_b}\,\gamma_{\inf}(b)`: the two intervals intersect."""
    lo_a, hi_a = gamma_interval(a)
    lo_b, hi_b = gamma_interval(b, factor_b)
    assert lo_a <= hi_b and lo_b <= hi_a, (
        f"certified gammas disagree: {a.gamma!r} vs {factor_b!r} * {b.gamma!r}\n" + describe(a, b)
    )


def assert_gamma_at_least(big: LMIResult, small: LMIResult) -> None:
    r""":math:`\gamma_{\inf}(\text{big}) \ge \gamma_{\inf}(\text{small})`."""
    assert gamma_interval(big)[1] >= gamma_interval(small)[0], (
        f"gamma {big.gamma!r} ({big.condition}) is below {small.gamma!r} ({small.condition})\n"
        + describe(big, small)
    )


def abscissa_tolerance(L: Matrix) -> float:
    r"""How far two computed spectral abscissae of operators similar to ``L`` may differ.

    A simple dominant eigenvalue is computed to about eps ``||L||`` times its condition
    number: :data:`ABSCISSA_RTOL` (1e-8) relative. A cluster of ``k`` eigenvalues at the
    abscissa may be a Jordan block (easily drawn: repeated eigenvalues of some
    :math:`A_s` give defective eigenvalues of :math:`I \otimes A_s + A_s \otimes I`), and
    a defective eigenvalue is only determined to :math:`(\varepsilon \|L\|)^{1/k}`
    (Wilkinson), so that, times 10, is allowed when ``k > 1``.
    """
    ev = np.linalg.eigvals(L)
    scale = max(1.0, float(np.linalg.norm(L, 2)))
    top = ev[np.argmax(ev.real)]
    k = int(np.sum(np.abs(ev - top) <= 1e-3 * scale))
    tol = max(ABSCISSA_RTOL * abs(top.real), ABSCISSA_ATOL_REL * scale)
    if k > 1:
        tol = max(tol, 10.0 * (np.finfo(float).eps * scale) ** (1.0 / k))
    return tol


def assert_abscissa_close(a: float, b: float, L: Matrix, what: str) -> None:
    """Two spectral abscissae of operators similar to ``L`` agree (:func:`abscissa_tolerance`)."""
    tol = abscissa_tolerance(L)
    assert abs(a - b) <= tol, f"{what}: spectral abscissa {a!r} vs {b!r} (difference {abs(a - b):.3e} > {tol:.3e})"


def certified_gamma(drawn: DrawnLoop, *, robust: bool) -> LMIResult:
    """``hinf_gamma`` of the drawn loop; the example is skipped unless it is certified."""
    res = hinf_gamma(drawn.loop, robust=robust)
    event(f"{res.condition}: {res.outcome}")
    if res.certified:
        event(f"{res.condition}: rung {ladder_rung(res):g}")
    note(describe(res))
    assume(res.certified)
    return res


def theorem_3_1_blocks(drawn: DrawnLoop, P: tuple[Matrix, ...], beta: Matrix) -> list[Matrix]:
    r""":math:`\Pi_s = A_s^T P_s + P_s A_s + \sum_{s'} Q(\beta)_{s s'} P_{s'}` for every
    joint mode, rebuilt from the chain's generator (independently of ``ftc_verify.analysis.lmi``)."""
    Q = drawn.system.chain.generator(beta)
    loop = drawn.loop
    return [A.T @ P[s] + P[s] @ A + sum(Q[s, t] * P[t] for t in range(len(P))) for s, A in enumerate(loop.A)]


def hinf_blocks(drawn: DrawnLoop, res: LMIResult, beta: Matrix, *, robust: bool) -> list[Matrix]:
    r"""Blocks of Theorem 3.2 / Lemma 4.1 at ``beta`` with the returned ``P``, multipliers
    and :math:`g = \gamma^2`, assembled here from the plant data (not from the loop):
    ``[[Pi + sum_k lam_k F_k' F_k, P E_1, ..., P D_i, C_i'], [., -lam_1 I, ...], ...,
    [., -g I, 0], [., 0, -I]]`` with channels :math:`(A1_i, A2_i)`, :math:`(B1_i, B2_i K_j)`."""
    assert res.P is not None and res.gamma is not None
    g = res.gamma**2
    m = drawn.system.m
    out = []
    for s, Pi in enumerate(theorem_3_1_blocks(drawn, res.P, beta)):
        i, j = divmod(s, m)
        md, K, P = drawn.system.modes[i], drawn.gains[j], res.P[s]
        chans: list[tuple[Matrix, Matrix]] = []
        if robust and md.A1 is not None and md.A2 is not None:
            chans.append((md.A1, md.A2))
        if robust and md.B1 is not None and md.B2 is not None:
            chans.append((md.B1, md.B2 @ K))
        lam = res.multipliers[s] if robust and res.multipliers is not None else ()
        assert len(lam) == len(chans), f"joint mode {s}: {len(lam)} multipliers for {len(chans)} channels"
        top = Pi + sum((lk * F.T @ F for lk, (_, F) in zip(lam, chans)), np.zeros_like(Pi))
        cols = [P @ E for E, _ in chans] + [P @ md.D, md.C.T]
        diag = [-lk * np.eye(E.shape[1]) for lk, (E, _) in zip(lam, chans)]
        diag += [-g * np.eye(md.D.shape[1]), -np.eye(md.C.shape[0])]
        k = len(cols)
        rows = [[top] + cols]
        for r in range(k):
            rows.append([cols[r].T] + [diag[r] if q == r else np.zeros((cols[r].shape[1], cols[q].shape[1])) for q in range(k)])
        out.append(np.block(rows))
    return out


def assert_negative_definite(blocks: list[Matrix], what: str) -> None:
    """Every symmetric block, assembled here in float, is proved negative definite in
    ball arithmetic (no margin relative to the block's norm: a certificate needs none,
    and a multiplier of a zero channel may be large)."""
    with precision():
        for s, M in enumerate(blocks):
            M = 0.5 * (M + M.T)
            eig = np.linalg.eigvalsh(M)
            assert eig[-1] < 0 and proven_positive_definite(ball(-M)), (
                f"{what}: block of joint mode {s} has largest eigenvalue {eig[-1]!r}"
            )


def box_points(drawn: DrawnLoop, fractions: Matrix) -> list[Matrix]:
    """Every vertex of the beta box and the interior point ``beta_min + f (beta_max - beta_min)``."""
    chain = drawn.system.chain
    return list(chain.vertices()) + [chain.beta_min + fractions * (chain.beta_max - chain.beta_min)]


# --------------------------------------------------------------------------- (a) Theorem 3.1


@given(
    drawn=st.one_of(
        stable_loops(margin=MARGIN, **small(uncertain=False), chains={**EXACT_BETA, "fault_during_delay": None}),
        unstable_loops(margin=MARGIN, **small(uncertain=False), chains={**EXACT_BETA, "fault_during_delay": None}),
    )
)
def test_theorem_3_1_iff_spectral_for_fixed_beta(drawn: DrawnLoop) -> None:
    r"""For a fixed :math:`\beta` (``beta_min == beta_max``) Theorem 3.1 is the exact
    Markov-jump Lyapunov test: :math:`\exists P_s > 0,\ \Pi_s < 0` iff
    :math:`\max\operatorname{Re}\lambda(\mathcal L(\beta)) < 0`. Away from the boundary
    (:math:`|\text{abscissa}| > 0.05`) the certified LMI outcome equals the spectral verdict."""
    mss = drawn.mss
    assert mss.exhaustive and mss.vertices_evaluated == 1
    res = mes_lmi(drawn.loop)
    event(f"{'stable' if mss.stable else 'unstable'} -> {res.outcome}")
    assert res.certified == mss.stable, (
        f"spectral abscissa {mss.spectral_abscissa!r} but Theorem 3.1 LMI {res.outcome}: {res.message}"
    )
    if res.certified:
        assert res.P is not None
        assert_negative_definite(theorem_3_1_blocks(drawn, res.P, drawn.system.chain.beta_min), "Theorem 3.1")


@given(
    drawn=closed_loops(**small(uncertain=False), gain_scale=st.sampled_from([1.0, 1.0, 0.6, 0.3])),
    fractions=matrices(3, 3, bound=1.0).map(np.abs),
)
def test_theorem_3_1_on_a_box_is_sufficient(drawn: DrawnLoop, fractions: Matrix) -> None:
    r"""On a :math:`\beta` box Theorem 3.1 is only sufficient: if it is certified, the
    returned :math:`P` makes :math:`\Pi_s(\beta) < 0` at every vertex and at an interior
    point (recomputed from the generator, so a transposed ``beta[fdi][true]`` index in the
    LMI blocks would show), and the loop is mean-square stable there:
    :math:`\max\operatorname{Re}\lambda(\mathcal L(\beta)) < 0`."""
    m = drawn.system.m
    points = box_points(drawn, fractions[:m, :m])
    res = mes_lmi(drawn.loop)
    event(f"Theorem 3.1 on a box: {res.outcome}; spectral {'stable' if drawn.mss.stable else 'unstable'}")
    abscissae = [spectral_abscissa(drawn.loop, b) for b in points]
    assert math.isclose(max(abscissae[:-1]), drawn.mss.spectral_abscissa, rel_tol=1e-12, abs_tol=1e-12)
    if not res.certified:
        # Only sufficient: an uncertified box says nothing; but a box with an unstable
        # vertex must never be certified, which the branch below asserts.
        assert res.outcome in ("candidate", "infeasible", "error")
        return
    assert res.P is not None
    for b in points:
        assert_negative_definite(theorem_3_1_blocks(drawn, res.P, b), f"Theorem 3.1 at beta={b.tolist()}")
    assert max(abscissae) < 0.0, f"certified box but spectral abscissae {abscissae}"


# --------------------------------------------------------------------------- (b) similarity


@pytest.mark.slow(16)  # seconds measured on 2 busy cores: scheduled first
@given(drawn=stable_loops(margin=MARGIN, **small()), data=st.data())
def test_similarity_invariance(drawn: DrawnLoop, data: st.DataObject) -> None:
    r"""A state change :math:`\tilde x = T x` (cond :math:`T \le 10`) maps
    :math:`\mathcal L` to a similar operator (:math:`\tilde X = T X T^T`) and the LMI
    solutions to :math:`\tilde P = T^{-T} P T^{-1}`: the spectral abscissa at every vertex
    is unchanged (rel. 1e-8) and so are the nominal and robust :math:`\gamma_{\inf}`
    (Lemma 4.1: :math:`\tilde P \tilde E = T^{-T} P E`, :math:`\tilde F^T\tilde F = T^{-T} F^T F T^{-1}`)."""
    T = data.draw(similarity_transforms(drawn.system.dims[0]), label="T")
    moved = similarity(drawn, T)
    for b in drawn.system.chain.vertices():
        assert_abscissa_close(spectral_abscissa(drawn.loop, b), spectral_abscissa(moved.loop, b),
                              second_moment_generator(drawn.loop, b), f"similarity at beta={b.tolist()}")
    a = certified_gamma(drawn, robust=False)
    b_ = certified_gamma(moved, robust=False)
    assert_same_gamma(a, b_)
    if drawn.system.uncertain:
        ra = certified_gamma(drawn, robust=True)
        rb = certified_gamma(moved, robust=True)
        assert_same_gamma(ra, rb)


# --------------------------------------------------------------------------- (c) relabelling


@pytest.mark.slow(7)  # seconds measured on 2 busy cores: scheduled first
@given(drawn=stable_loops(margin=MARGIN, **small(), chains={"fault_during_delay": None}), data=st.data())
def test_mode_relabelling_invariance(drawn: DrawnLoop, data: st.DataObject) -> None:
    r"""Renaming the modes by a permutation :math:`\pi` (plant tables, rows and columns of
    :math:`\alpha, \beta`, FDI gains) permutes the joint modes
    :math:`(i, j) \mapsto (\pi^{-1} i, \pi^{-1} j)`: :math:`\mathcal L` is permutation-similar,
    so the spectral abscissa at corresponding :math:`\beta` and the worst over the box are
    equal, and the LMIs are the same up to renaming, so :math:`\gamma_{\inf}` is equal."""
    m = drawn.system.m
    perm = data.draw(st.permutations(range(m)), label="perm")
    if list(perm) == list(range(m)):
        perm = perm[::-1]  # always a genuine relabelling
    moved = relabel(drawn, perm)
    p = np.asarray(perm)
    for b in drawn.system.chain.vertices():
        L = second_moment_generator(drawn.loop, b)
        assert_abscissa_close(spectral_abscissa(drawn.loop, b), spectral_abscissa(moved.loop, b[np.ix_(p, p)]),
                              L, f"relabelling {list(perm)} at beta={b.tolist()}")
    L = second_moment_generator(drawn.loop, drawn.mss.worst_beta)
    assert_abscissa_close(drawn.mss.spectral_abscissa, moved.mss.spectral_abscissa, L, "worst over the box")
    assert_same_gamma(certified_gamma(drawn, robust=False), certified_gamma(moved, robust=False))


# --------------------------------------------------------------------------- (d) scaling D


@pytest.mark.slow(8)  # seconds measured on 2 busy cores: scheduled first
@given(drawn=stable_loops(margin=MARGIN, **small(uncertain=False)), c=st.floats(0.2, 5.0))
def test_disturbance_scaling_scales_gamma(drawn: DrawnLoop, c: float) -> None:
    r""":math:`D_i \to c D_i` (:math:`c > 0`) scales the disturbance-to-output map by
    :math:`c`; in the LMI the congruence :math:`\operatorname{diag}(I, c^{-1} I, I)` maps
    a solution at :math:`g` to one at :math:`c^2 g` with the same :math:`P`, so
    :math:`\gamma_{\inf}(cD) = c\,\gamma_{\inf}(D)`."""
    base = certified_gamma(drawn, robust=False)
    scaled = certified_gamma(scale_disturbance(drawn, c), robust=False)
    assert_same_gamma(scaled, base, factor_b=c)


# --------------------------------------------------------------------------- (e) robust vs nominal


@pytest.mark.slow(11)  # seconds measured on 2 busy cores: scheduled first
@given(drawn=stable_loops(margin=MARGIN, **small(uncertain=True)), fractions=matrices(3, 3, bound=1.0).map(np.abs))
def test_robust_gamma_at_least_nominal(drawn: DrawnLoop, fractions: Matrix) -> None:
    r"""Lemma 4.1's block contains Theorem 3.2's block plus :math:`\lambda F^TF \succeq 0`
    in its corner and the extra :math:`P E` rows: deleting those rows and columns of a
    feasible robust block leaves a feasible nominal block, so
    :math:`\gamma_{\inf}^{rob} \ge \gamma_{\inf}^{nom}`. Both returned certificates also
    hold when rebuilt here from the plant data at every vertex and an interior point."""
    nominal = certified_gamma(drawn, robust=False)
    robust = certified_gamma(drawn, robust=True)
    assert_gamma_at_least(robust, nominal)
    for b in box_points(drawn, fractions[: drawn.system.m, : drawn.system.m]):
        assert_negative_definite(hinf_blocks(drawn, nominal, b, robust=False), f"Theorem 3.2 at beta={b.tolist()}")
        assert_negative_definite(hinf_blocks(drawn, robust, b, robust=True), f"Lemma 4.1 at beta={b.tolist()}")


@pytest.mark.slow(10)  # seconds measured on 2 busy cores: scheduled first
@given(drawn=stable_loops(margin=MARGIN, **small(uncertain=True), zero_weights=True))
def test_robust_gamma_equals_nominal_for_zero_weights(drawn: DrawnLoop) -> None:
    r"""With :math:`A_1 = A_2 = B_1 = B_2 = 0` the uncertainty channels vanish
    (:math:`E = F = 0`): Lemma 4.1's block is Theorem 3.2's block plus a decoupled
    :math:`-\lambda I`, so :math:`\gamma_{\inf}^{rob} = \gamma_{\inf}^{nom}`."""
    assert drawn.loop.uncertain  # zero weights still give channels (the code path under test)
    nominal = certified_gamma(drawn, robust=False)
    robust = certified_gamma(drawn, robust=True)
    assert_same_gamma(robust, nominal)


def perturbed_nominal(drawn: DrawnLoop, deltas: list[tuple[Matrix, Matrix]]) -> DrawnLoop:
    r"""The nominal plant with fixed :math:`A_i + A1_i \Delta_{1,i} A2_i` and
    :math:`B_i + B1_i \Delta_{2,i} B2_i`, same gains, no uncertainty weights."""
    spec = drawn.spec()
    for md, (d1, d2) in zip(spec["modes"], deltas):
        md["A"] = md["A"] + md.pop("A1") @ d1 @ md.pop("A2")
        md["B"] = md["B"] + md.pop("B1") @ d2 @ md.pop("B2")
    return DrawnLoop.from_spec(**spec)


def unit_norm(M: Matrix) -> Matrix:
    """``M / ||M||_2`` (spectral norm 1, on the boundary of the uncertainty set); 0 stays 0."""
    norm = float(np.linalg.norm(M, 2))
    return M / norm if norm > 0.0 else M


@pytest.mark.slow(9)  # seconds measured on 2 busy cores: scheduled first
@given(drawn=stable_loops(margin=MARGIN, **small(uncertain=True)), data=st.data())
def test_robust_certificate_covers_every_fixed_delta(drawn: DrawnLoop, data: st.DataObject) -> None:
    r"""Lemma 4.1 bounds every admissible :math:`\Delta` (time-varying, so in particular
    any fixed :math:`\|\Delta_{1,i}\|, \|\Delta_{2,i}\| \le 1` per mode): if it is certified
    at :math:`\gamma`, the plant with those :math:`\Delta` built in is mean-square stable at
    every vertex of the box and its nominal :math:`\gamma_{\inf}` is at most :math:`\gamma`."""
    robust = certified_gamma(drawn, robust=True)
    n, nu, _, _ = drawn.system.dims
    deltas = [
        (unit_norm(data.draw(matrices(n, n, bound=1.0), label=f"Delta1[{i}]")),
         unit_norm(data.draw(matrices(nu, nu, bound=1.0), label=f"Delta2[{i}]")))
        for i in range(drawn.system.m)
    ]
    fixed = perturbed_nominal(drawn, deltas)
    assert fixed.mss.spectral_abscissa < 0.0, (
        f"Lemma 4.1 certified ({robust.message}) but a fixed Delta gives spectral abscissa "
        f"{fixed.mss.spectral_abscissa!r} at beta={fixed.mss.worst_beta.tolist()}"
    )
    assert_gamma_at_least(robust, certified_gamma(fixed, robust=False))


# --------------------------------------------------------------------------- (f) beta box


@given(
    drawn=stable_loops(margin=MARGIN, **small(uncertain=False), chains=ANY_BETA),
    shrink=matrices(3, 3, bound=0.9).map(np.abs),
    grow=matrices(3, 3, bound=2.0).map(np.abs),
)
@pytest.mark.slow(7)  # seconds measured on 2 busy cores: scheduled first
def test_wider_beta_box_never_lowers_gamma(drawn: DrawnLoop, shrink: Matrix, grow: Matrix) -> None:
    r"""The LMIs hold on a box iff they hold at its rate ends; a wider box
    :math:`[\beta^-(1-s), \beta^+ + w] \supseteq [\beta^-, \beta^+]` imposes a superset of
    constraints, so its :math:`\gamma_{\inf}` is not smaller."""
    m = drawn.system.m
    chain = drawn.system.chain
    off = ~np.eye(m, dtype=bool)
    wide = with_beta_box(
        drawn,
        np.where(off, chain.beta_min * (1.0 - shrink[:m, :m]), 0.0),
        np.where(off, chain.beta_max + grow[:m, :m], 0.0),
    )
    narrow_res = certified_gamma(drawn, robust=False)
    wide_res = certified_gamma(wide, robust=False)
    assert_gamma_at_least(wide_res, narrow_res)


# --------------------------------------------------------------------------- (g) dynamic controllers


@given(
    drawn=closed_loops(**small(), m=(2, 3), measured_outputs=st.one_of(st.none(), st.integers(1, 2)),
                       dynamic=True, extra_states=(0, 2), chains=ANY_BETA),
    fractions=matrices(3, 3, bound=1.0).map(np.abs),
    data=st.data(),
)
def test_controller_state_change_keeps_the_loop(drawn: DrawnLoop, fractions: Matrix, data: st.DataObject) -> None:
    r"""A dynamic output-feedback controller of order :math:`n_c` gives a loop on the
    augmented state :math:`(x, x_c)` of dimension :math:`n + n_c`, plant states first.
    A change of controller coordinates :math:`\tilde x_c = T x_c` (cond :math:`T \le 10`:
    :math:`A_c \to T A_c T^{-1}`, :math:`B_c \to T B_c`, :math:`C_c \to C_c T^{-1}`)
    maps every joint-mode matrix by :math:`\operatorname{diag}(I, T)` and the
    second-moment generator to a similar one, so the spectral abscissa is unchanged (rel.
    1e-8, :func:`abscissa_tolerance`) at the two extreme vertices and an interior point
    of the box (all :math:`2^{m(m-1)}` vertices cost seconds for :math:`m = 3`)."""
    n, n_c = drawn.system.dims[0], drawn.controller.n_c
    assert n_c >= n and not drawn.controller.static
    assert drawn.loop.n == n + n_c and drawn.loop.n_plant == n
    T = data.draw(similarity_transforms(n_c), label="T")
    moved = controller_similarity(drawn, T)
    assert moved.loop.n == n + n_c
    m, chain = drawn.system.m, drawn.system.chain
    interior = chain.beta_min + fractions[:m, :m] * (chain.beta_max - chain.beta_min)
    for b in (chain.beta_min, chain.beta_max, interior):
        L = second_moment_generator(drawn.loop, b)
        before = spectral_abscissa(drawn.loop, b)
        assert_abscissa_close(before, spectral_abscissa(moved.loop, b), L,
                              f"controller state change at beta={b.tolist()}")
    event(f"n_c - n = {n_c - n}; {'stable' if before < 0 else 'unstable'} at an interior beta")


def test_gamma_tolerance_helpers_can_fail() -> None:
    """The comparison helpers reject gammas that differ by more than the tolerance."""
    from ftc_verify.analysis.lmi import Certificate

    def fake(gamma: float, rung: float) -> LMIResult:
        cert = Certificate(True, "theorem-3.2", (), 1.0, 1.0, gamma)
        return LMIResult("theorem-3.2", "certified", gamma, "clarabel", "optimal", 0.0, 0.0, cert,
                         message=f"minimum x from step 1; certified at {gamma} (+{rung:g} relative)")

    assert_same_gamma(fake(1.0, 1e-4), fake(1.001, 1e-3))
    with pytest.raises(AssertionError):
        assert_same_gamma(fake(1.0, 1e-4), fake(1.02, 1e-4))
    assert_same_gamma(fake(1.0, 1e-4), fake(1.04, 5e-2))  # the larger rung widens its lower side
    with pytest.raises(AssertionError):
        assert_gamma_at_least(fake(1.0, 1e-4), fake(1.02, 1e-4))
