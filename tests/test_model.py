"""Unit tests of ftc_verify.model.system: validation, the joint generator, the beta box."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from ftc_verify.errors import ValidationError
from ftc_verify.model.system import GENERATOR_RTOL, FTCSystem, JointChain, Mode, as_matrix

ALPHA2 = [[-0.5, 0.5], [1.0, -1.0]]
BMIN2 = [[0.0, 2.0], [2.5, 0.0]]
BMAX2 = [[0.0, 3.0], [3.5, 0.0]]


def good_mode(n=2, nu=2, ny=1, nw=1, **extra):
    md = {
        "A": np.eye(n) * -1.0,
        "B": np.ones((n, nu)),
        "C": np.ones((ny, n)),
        "D": np.ones((n, nw)),
    }
    md.update(extra)
    return md


def build(modes=None, alpha=ALPHA2, beta_min=BMIN2, beta_max=BMAX2):
    if modes is None:
        modes = [good_mode(), good_mode()]
    return FTCSystem.from_arrays(name="t", modes=modes, alpha=alpha, beta_min=beta_min, beta_max=beta_max)


def raises_naming(fn, *fragments):
    """Call fn, expect ValidationError whose message contains every fragment."""
    with pytest.raises(ValidationError) as info:
        fn()
    msg = str(info.value)
    for frag in fragments:
        assert frag in msg, f"{frag!r} not in message {msg!r}"
    return msg


# ============================================================================ validation
def test_validation_error_is_value_error():
    assert issubclass(ValidationError, ValueError)


def test_valid_system_builds():
    s = build()
    assert s.m == 2 and s.dims == (2, 2, 1, 1) and not s.uncertain


def test_negative_off_diagonal_alpha():
    raises_naming(lambda: JointChain([[0.5, -0.5], [1.0, -1.0]], BMIN2, BMAX2), "chain.alpha[1][2]", "-0.5")


def test_alpha_row_not_summing_to_zero():
    msg = raises_naming(lambda: JointChain([[-0.5, 0.5], [1.0, -0.75]], BMIN2, BMAX2), "chain.alpha", "row 2")
    assert "0.25" in msg  # the offending sum (or the row) is shown


def test_alpha_row_sum_within_relative_tolerance_is_accepted():
    # 1e-12 relative to the largest rate: well inside GENERATOR_RTOL.
    big = 1000.0
    chain = JointChain([[-big, big * (1 + 1e-12)], [2.0, -2.0]], BMIN2, BMAX2)
    assert chain.m == 2


@pytest.mark.parametrize("factor, ok", [(0.5, True), (2.0, False)])
def test_alpha_row_sum_tolerance_boundary(factor, ok):
    big = 1000.0
    err = factor * GENERATOR_RTOL * big  # tolerance is GENERATOR_RTOL * max(1, max|alpha|)
    alpha = [[-big, big + err], [2.0, -2.0]]
    if ok:
        assert JointChain(alpha, BMIN2, BMAX2).m == 2
    else:
        raises_naming(lambda: JointChain(alpha, BMIN2, BMAX2), "chain.alpha", "row 1")


def test_beta_min_exceeds_beta_max():
    bmin = [[0.0, 3.25], [2.5, 0.0]]
    raises_naming(lambda: JointChain(ALPHA2, bmin, BMAX2), "beta_min[1][2]", "3.25", "3.0")


@pytest.mark.parametrize(
    "bmin, bmax, field, value",
    [
        ([[0.0, 2.0], [-1.5, 0.0]], BMAX2, "chain.beta_min[2][1]", "-1.5"),
        ([[0.0, 2.0], [0.0, 0.0]], [[0.0, 3.0], [-0.25, 0.0]], "chain.beta_max[2][1]", "-0.25"),
    ],
)
def test_negative_rate(bmin, bmax, field, value):
    raises_naming(lambda: JointChain(ALPHA2, bmin, bmax), field, value)


@pytest.mark.parametrize(
    "where, bad, text",
    [
        ("alpha", math.nan, "nan"),
        ("alpha", math.inf, "inf"),
        ("beta_min", math.nan, "nan"),
        ("beta_max", math.inf, "inf"),
    ],
)
def test_non_finite_chain_entries(where, bad, text):
    args = {"alpha": [r[:] for r in ALPHA2], "beta_min": [r[:] for r in BMIN2], "beta_max": [r[:] for r in BMAX2]}
    args[where][0][1] = bad
    raises_naming(lambda: JointChain(args["alpha"], args["beta_min"], args["beta_max"]), f"chain.{where}", text)


@pytest.mark.parametrize("key", ["A", "B", "C", "D"])
@pytest.mark.parametrize("bad, text", [(math.nan, "nan"), (-math.inf, "-inf")])
def test_non_finite_mode_entries(key, bad, text):
    md = good_mode()
    M = np.array(md[key], dtype=float)
    M[0, 0] = bad
    md[key] = M
    raises_naming(lambda: build([good_mode(), md]), f"mode 2.{key}", text)


@pytest.mark.parametrize(
    "second, field, value",
    [
        (good_mode(n=3), "n", "3"),
        (good_mode(nu=3), "nu", "3"),
        (good_mode(ny=2), "ny", "2"),
        (good_mode(nw=4), "nw", "4"),
    ],
)
def test_inconsistent_dimensions_across_modes(second, field, value):
    msg = raises_naming(lambda: build([good_mode(), second]), "mode 2")
    assert re.search(rf"\b{field}\b", msg), msg
    assert re.search(rf"=\s*{value}\b", msg), msg


@pytest.mark.parametrize(
    "key, value",
    [
        ("A", [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),  # not square
        ("B", [[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]]),  # 3 rows, n = 2
        ("C", [[1.0, 2.0, 3.0]]),  # 3 columns
        ("D", [[0.5]]),  # 1 row
    ],
)
def test_wrong_shape_inside_mode(key, value):
    md = good_mode()
    md[key] = value
    raises_naming(lambda: build([good_mode(), md]), f"mode 2.{key}", str(value))


@pytest.mark.parametrize(
    "extra, field",
    [
        ({"A1": np.ones((3, 1)), "A2": np.ones((1, 2))}, "A1"),
        ({"A1": np.ones((2, 1)), "A2": np.ones((1, 3))}, "A2"),
        ({"B1": np.ones((1, 1)), "B2": np.ones((1, 2))}, "B1"),
        ({"B1": np.ones((2, 1)), "B2": np.ones((1, 3))}, "B2"),  # nu = 2
    ],
)
def test_wrong_uncertainty_shape(extra, field):
    md = good_mode(**extra)
    raises_naming(lambda: build([md, good_mode()]), f"mode 1.{field}", str(np.asarray(extra[field]).tolist()))


def test_fewer_than_two_modes_in_chain():
    raises_naming(lambda: JointChain([[0.0]], [[0.0]], [[0.0]]), "chain.alpha", "1")


def test_fewer_mode_tables_than_chain_modes():
    raises_naming(lambda: build([good_mode()]), "1 mode", "2")


def test_non_square_alpha():
    raises_naming(lambda: JointChain([[-1.0, 1.0, 0.0], [1.0, -1.0, 0.0]], BMIN2, BMAX2), "chain.alpha", "(2, 3)")


def test_beta_bounds_shape_must_match_alpha():
    raises_naming(lambda: JointChain(ALPHA2, [[0.0, 1.0, 1.0]] * 3, BMAX2), "chain.beta_min", "(3, 3)")


@pytest.mark.parametrize("value", [[[]], [], [[], []]])
def test_empty_matrix(value):
    md = good_mode()
    md["A"] = value
    raises_naming(lambda: build([md, good_mode()]), "mode 1.A")


def test_empty_alpha():
    raises_naming(lambda: JointChain([[]], BMIN2, BMAX2), "chain.alpha")


@pytest.mark.parametrize(
    "given, missing",
    [("A1", "A2"), ("A2", "A1"), ("B1", "B2"), ("B2", "B1")],
)
def test_uncertainty_weight_without_partner(given, missing):
    md = good_mode(**{given: np.eye(2)})
    msg = raises_naming(lambda: build([md, good_mode()]), f"mode 1.{missing}")
    assert given in msg


@pytest.mark.parametrize(
    "value",
    [[[1.0, 2.0], [3.0]], [[1.0], [2.0, 3.0]]],
)
def test_ragged_lists(value):
    md = good_mode()
    md["A"] = value
    raises_naming(lambda: build([md, good_mode()]), "mode 1.A", str(value))


def test_non_numeric_entry():
    raises_naming(lambda: as_matrix([[1.0, "x"]], "K"), "K", "'x'")


@pytest.mark.parametrize("value", [[["1.0", "2.0"]], [[True, False]]])
def test_as_matrix_rejects_strings_and_booleans(value):
    # as_matrix documents "rejects ... non-numeric input"; numpy's float() conversion
    # silently turns "1.0" into 1.0 and True into 1.0, so a problem file with quoted
    # numbers or booleans would be accepted without complaint.
    with pytest.raises(ValidationError) as info:
        as_matrix(value, "mode 1.A")
    assert "mode 1.A" in str(info.value)


def test_as_matrix_is_read_only():
    M = as_matrix([[1, 2], [3, 4]], "x")
    assert M.dtype == np.float64
    with pytest.raises(ValueError):
        M[0, 0] = 5.0


def test_unknown_and_missing_mode_keys_from_arrays():
    raises_naming(lambda: build([good_mode(E=np.eye(2)), good_mode()]), "mode 1", "E")
    md = good_mode()
    del md["C"]
    raises_naming(lambda: build([good_mode(), md]), "mode 2", "C")


def test_mode_equality_and_uncertain_flag():
    m1 = Mode(**good_mode(A1=np.eye(2), A2=np.eye(2)))
    m2 = Mode(**good_mode(A1=np.eye(2), A2=np.eye(2)))
    assert m1 == m2 and m1.uncertain
    assert Mode(**good_mode()) != m1 and not Mode(**good_mode()).uncertain


# ============================================================================ joint generator
# Two modes, all four rates distinct so that a swapped index shows.
A01, A10 = 0.7, 1.3
B_FDI0_TRUE1, B_FDI1_TRUE0 = 2.9, 4.1  # beta[0][1], beta[1][0]
ALPHA_D = [[-A01, A01], [A10, -A10]]
BETA_D = [[0.0, B_FDI0_TRUE1], [B_FDI1_TRUE0, 0.0]]


def chain2(fault_during_delay=False):
    return JointChain(ALPHA_D, [[0.0, 2.0], [4.0, 0.0]], [[0.0, 3.0], [5.0, 0.0]], fault_during_delay)


def test_joint_mode_order():
    assert chain2().joint_modes == ((0, 0), (0, 1), (1, 0), (1, 1))


def test_generator_two_modes_by_hand():
    # s = true*2 + fdi: 0=(0,0) 1=(0,1) 2=(1,0) 3=(1,1)
    # (0,0)->(1,0) alpha01 ; (1,1)->(0,1) alpha10 ;
    # (0,1)->(0,0) beta[1][0] ; (1,0)->(1,1) beta[0][1]
    expected = np.array([
        [-A01, 0.0, A01, 0.0],
        [B_FDI1_TRUE0, -B_FDI1_TRUE0, 0.0, 0.0],
        [0.0, 0.0, -B_FDI0_TRUE1, B_FDI0_TRUE1],
        [0.0, A10, 0.0, -A10],
    ])
    Q = chain2().generator(BETA_D)
    np.testing.assert_allclose(Q, expected, rtol=0, atol=1e-15)
    np.testing.assert_allclose(Q.sum(axis=1), 0.0, atol=1e-14)


def test_generator_two_modes_fault_during_delay_by_hand():
    # Variant: additionally (0,1)->(1,1) at alpha01 and (1,0)->(0,0) at alpha10.
    expected = np.array([
        [-A01, 0.0, A01, 0.0],
        [B_FDI1_TRUE0, -B_FDI1_TRUE0 - A01, 0.0, A01],
        [A10, 0.0, -B_FDI0_TRUE1 - A10, B_FDI0_TRUE1],
        [0.0, A10, 0.0, -A10],
    ])
    Q = chain2(fault_during_delay=True).generator(BETA_D)
    np.testing.assert_allclose(Q, expected, rtol=0, atol=1e-15)
    np.testing.assert_allclose(Q.sum(axis=1), 0.0, atol=1e-14)


# Three modes: every rate distinct.
ALPHA3_OFF = np.array([[0.0, 0.11, 0.13], [0.17, 0.0, 0.19], [0.23, 0.29, 0.0]])
ALPHA3 = ALPHA3_OFF - np.diag(ALPHA3_OFF.sum(axis=1))
BETA3 = np.array([[0.0, 2.3, 3.1], [3.7, 0.0, 4.3], [5.3, 5.9, 0.0]])  # beta[fdi][true]


def chain3(fault_during_delay=False):
    return JointChain(ALPHA3, BETA3 - 0.5 * (BETA3 > 0), BETA3 + 0.5 * (BETA3 > 0), fault_during_delay)


@pytest.mark.parametrize("fdd", [False, True])
def test_generator_three_modes_matches_reading_notes(ref, fdd):
    Q = chain3(fdd).generator(BETA3)
    np.testing.assert_allclose(Q, ref.joint_generator(ALPHA3, BETA3, fdd), rtol=0, atol=1e-14)
    np.testing.assert_allclose(Q.sum(axis=1), 0.0, atol=1e-14)
    off = Q - np.diag(np.diag(Q))
    assert np.all(off >= 0)
    # number of transitions: m(m-1) faults + m(m-1) detections (+ m(m-1)(m-1) in the variant)
    assert np.count_nonzero(off) == (6 + 6 + (12 if fdd else 0))


def test_generator_three_modes_specific_entries():
    Q = chain3().generator(BETA3)
    s = lambda i, j: 3 * i + j  # noqa: E731
    # fault from (1,1) to true 2, FDI still 1, at alpha[1][2]
    assert Q[s(1, 1), s(2, 1)] == pytest.approx(ALPHA3[1, 2])
    # detection from (true 2, fdi 0) back to (2,2) at beta[fdi=0][true=2]
    assert Q[s(2, 0), s(2, 2)] == pytest.approx(BETA3[0, 2])
    assert Q[s(0, 2), s(0, 0)] == pytest.approx(BETA3[2, 0])
    # paper model: no fault while the FDI lags, no FDI move other than to the true mode
    assert Q[s(2, 0), s(1, 0)] == 0.0
    assert Q[s(2, 0), s(2, 1)] == 0.0
    assert Q[s(1, 1), s(1, 2)] == 0.0
    # row (i, j) with i != j leaves at exactly beta[j][i]
    assert -Q[s(1, 2), s(1, 2)] == pytest.approx(BETA3[2, 1])


def test_generator_three_modes_variant_specific_entries():
    Q = chain3(fault_during_delay=True).generator(BETA3)
    s = lambda i, j: 3 * i + j  # noqa: E731
    assert Q[s(2, 0), s(1, 0)] == pytest.approx(ALPHA3[2, 1])
    assert Q[s(2, 0), s(0, 0)] == pytest.approx(ALPHA3[2, 0])
    assert Q[s(2, 0), s(2, 2)] == pytest.approx(BETA3[0, 2])
    assert -Q[s(2, 0), s(2, 0)] == pytest.approx(BETA3[0, 2] - ALPHA3[2, 2])


def test_generator_ignores_beta_diagonal():
    b = np.array(BETA_D)
    b[0, 0] = b[1, 1] = 2.5  # diagonal is meaningless; must not enter Q
    np.testing.assert_array_equal(chain2().generator(b), chain2().generator(BETA_D))


# ============================================================================ beta box
def test_vertices_two_modes():
    ch = chain2()
    verts = list(ch.vertices())
    assert len(verts) == 4 == ch.vertex_count()
    keys = {tuple(v.ravel()) for v in verts}
    assert keys == {
        (0.0, 2.0, 4.0, 0.0), (0.0, 2.0, 5.0, 0.0), (0.0, 3.0, 4.0, 0.0), (0.0, 3.0, 5.0, 0.0),
    }


def test_vertices_three_modes_distinct_and_on_box():
    ch = chain3()
    verts = list(ch.vertices())
    assert len(verts) == 2 ** 6 == ch.vertex_count()
    assert len({tuple(v.ravel()) for v in verts}) == 64
    off = ~np.eye(3, dtype=bool)
    for v in verts:
        assert np.all(np.diag(v) == 0.0)
        assert np.all((v[off] == ch.beta_min[off]) | (v[off] == ch.beta_max[off]))
        ch.check_beta(v)


def test_vertices_collapse_degenerate_intervals():
    bmin = BETA3.copy()
    bmax = BETA3 + 0.5 * (BETA3 > 0)
    bmax[0, 1] = bmin[0, 1]  # two degenerate intervals
    bmax[2, 0] = bmin[2, 0]
    ch = JointChain(ALPHA3, bmin, bmax)
    verts = list(ch.vertices())
    assert len(verts) == 16 == ch.vertex_count()
    assert len({tuple(v.ravel()) for v in verts}) == 16
    assert all(v[0, 1] == bmin[0, 1] and v[2, 0] == bmin[2, 0] for v in verts)


def test_check_beta_rejects_out_of_bounds_naming_entry():
    ch = chain2()  # beta[1][2] in [2, 3], beta[2][1] in [4, 5] (1-based, as in messages)
    raises_naming(lambda: ch.check_beta([[0.0, 2.5], [5.75, 0.0]]), "beta[2][1]", "5.75", "[4.0, 5.0]")
    raises_naming(lambda: ch.check_beta([[0.0, 1.5], [4.5, 0.0]]), "beta[1][2]", "1.5")
    raises_naming(lambda: ch.generator([[0.0, 3.5], [4.5, 0.0]]), "beta[1][2]", "3.5")
    np.testing.assert_array_equal(ch.check_beta([[0.0, 3.0], [4.0, 0.0]]), [[0.0, 3.0], [4.0, 0.0]])


def test_check_beta_wrong_shape():
    raises_naming(lambda: chain2().check_beta(np.zeros((3, 3))), "beta", "(3, 3)")


def test_row_rate_points_and_row_generator(ref):
    ch = chain2()
    s01, s10, s00 = ch.state_index(0, 1), ch.state_index(1, 0), ch.state_index(0, 0)
    assert [p[1, 0] for p in ch.row_rate_points(s01)] == [4.0, 5.0]  # row (true 0, fdi 1) uses beta[1][0]
    assert [p[0, 1] for p in ch.row_rate_points(s10)] == [2.0, 3.0]
    assert ch.row_rates(s00) == () and len(ch.row_rate_points(s00)) == 1
    assert ch.row_label(s01, ch.row_rate_points(s01)[1]) == "beta[2][1]=5"
    full = ref.joint_generator(ALPHA_D, [[0.0, 2.5], [4.75, 0.0]])
    point = ch.midpoint().copy()
    point[1, 0] = 4.75
    np.testing.assert_allclose(ch.row_generator(s01, point), full[1], atol=1e-15)
