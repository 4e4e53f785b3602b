r"""Properties of verdicts and certificates on loops in badly chosen coordinates (issue 20).

For an identical-mode loop (:mod:`ftc_verify.testing.illconditioned`) the truth is known
independently of this project's numerics: the second-moment abscissa is
:math:`2\alpha(A)` and the stochastic :math:`H_\infty` norm is the LTI norm, which SLICOT's
``ab13dd`` computes (through :func:`control.linfnorm`). Drawn loops are moved by a
diagonal change of units of condition up to 1e6 and a non-orthogonal similarity of
condition up to 1e4.

* the verdict never contradicts the true abscissa (and, at least 0.05 away from the
  boundary, it is decided);
* the certified nominal gamma is at least the true norm (a certificate is a proof) and
  within 1e-3 above it.
"""

from __future__ import annotations

import pytest
from hypothesis import given, note
from hypothesis import strategies as st

from ftc_verify.analysis.analyze import analyze
from ftc_verify.analysis.moments.stability import mean_square_stability
from ftc_verify.testing.illconditioned import PeerLoop, peer_loops

pytest.importorskip("slycot")


@given(peer_loops(max_n=7))
def test_certified_gamma_reaches_slicot_on_badly_conditioned_loops(p: PeerLoop) -> None:
    ref = p.reference_norm()
    rep = analyze(p.loop, cross_validation=False)
    note(f"n={p.loop.n} diag cond {p.diagonal_condition:.3g} transform cond {p.transform_condition:.3g} "
         f"ref {ref!r}: {rep.nominal.outcome} {rep.nominal.gamma!r} ({rep.nominal.message})")
    assert rep.mss.verdict == "stable"
    assert rep.nominal.certified
    assert ref * (1 - 1e-9) <= rep.nominal.gamma <= ref * (1 + 1e-3)
    assert rep.certified_stable


@given(st.sampled_from([-0.5, -0.05, 0.05, 0.5]).flatmap(lambda a: st.tuples(st.just(a), peer_loops(max_n=7, abscissa=a))))
def test_verdict_never_contradicts_the_true_abscissa(drawn: tuple[float, PeerLoop]) -> None:
    target, p = drawn
    r = mean_square_stability(p.loop)
    note(f"true abscissa {target}, estimate {r.spectral_abscissa!r}, {r.verdict}: {[v.method for v in r.vertex_verdicts]}")
    assert r.verdict == ("stable" if target < 0 else "not stable")
