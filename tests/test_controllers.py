"""The controller type, its files, and the one closed loop built from (system, controller).

Solver tolerance for the gamma comparisons: Clarabel with ``tol_gap_abs = tol_gap_rel =
tol_feas = 1e-9``; the certified gamma is the first rung of the re-centring ladder (1e-5
relative and up) whose certificate passes, so two equivalent loops may differ by the
ladder's first rung: the test allows 2e-4 relative.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

from ftc_verify.analysis import analyze, closed_loop, mean_square_stability, state_feedback_loop
from ftc_verify.analysis.moments.stability import spectral_abscissa
from ftc_verify.controllers import Controller, dump_controller, load_controller, save_controller
from ftc_verify.errors import ProblemFileError, ValidationError
from ftc_verify.model import FTCSystem, Mode, dump_system, load_system
from ftc_verify.analysis.moments.energy import exact_energy

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "examples" / "paper.toml"
PAPER_GAINS = ROOT / "examples" / "paper_gains.toml"
GAMMA_RTOL = 2e-4


def lifted(gains: tuple[np.ndarray, ...], a: float) -> Controller:
    """The dynamic controller ``Ac = -a I, Bc = 0, Cc = 0, Dc = K`` (reads ``y_m = I x``)."""
    nu, n = gains[0].shape
    return Controller.dynamic([-a * np.eye(n)] * len(gains), [np.zeros((n, n))] * len(gains),
                              [np.zeros((nu, n))] * len(gains), list(gains))


def first_moment_abscissa(loop, beta) -> float:
    """Spectral abscissa of the first-moment generator ``blockdiag(A_s) + Q' (x) I``."""
    import scipy.linalg

    Q = loop.chain.generator(beta)
    L = scipy.linalg.block_diag(*loop.A) + np.kron(Q.T, np.eye(loop.n))
    return float(np.max(np.linalg.eigvals(L).real))


def random_system(seed: int) -> FTCSystem:
    rng = np.random.default_rng(seed)
    n, nu, m = 3, 2, 2
    modes = [dict(A=rng.normal(size=(n, n)) - 2 * np.eye(n), B=rng.normal(size=(n, nu)), C=rng.normal(size=(1, n)),
                  D=rng.normal(size=(n, 1)), A1=0.1 * np.eye(n), A2=0.1 * np.eye(n), B1=0.1 * np.eye(n),
                  B2=0.1 * np.ones((1, nu))) for _ in range(m)]
    return FTCSystem.from_arrays(name=f"random-{seed}", modes=modes, alpha=[[-1.0, 1.0], [2.0, -2.0]],
                                 beta_min=[[0.0, 2.0], [1.0, 0.0]], beta_max=[[0.0, 4.0], [3.0, 0.0]])


# ------------------------------------------------------------------ equivalence

@pytest.fixture(scope="module")
def paper() -> tuple[FTCSystem, tuple[np.ndarray, ...]]:
    return load_system(PAPER), load_controller(PAPER_GAINS).gains


def test_lifted_loop_spectrum_is_the_union_of_the_parts(paper) -> None:
    """``Ac = -I`` adds the decoupled blocks ``-2`` (E[x_c x_c']) and first-moment - 1
    (E[x x_c']) to the spectrum; the plant block is unchanged (exact, 1e-9)."""
    system, gains = paper
    static = state_feedback_loop(system, gains)
    dynamic = closed_loop(system.with_measured_output(np.eye(2)), lifted(gains, 1.0))
    assert dynamic.n == 4 and dynamic.n_plant == 2
    for beta in system.chain.vertices():
        expected = max(spectral_abscissa(static, beta), -2.0, first_moment_abscissa(static, beta) - 1.0)
        assert spectral_abscissa(dynamic, beta) == pytest.approx(expected, abs=1e-9)


@pytest.mark.parametrize("seed", [None, 1, 4, 5])
def test_lifted_controller_equals_static_gains(paper, seed) -> None:
    """With ``Ac = -a I`` fast enough, every number equals the state-feedback one."""
    if seed is None:
        system, gains = paper
    else:
        system = random_system(seed)
        gains = tuple(-md.B.T @ scipy.linalg.solve_continuous_are(md.A, md.B, np.eye(3), np.eye(2))
                      for md in system.modes)  # per-mode LQR: mean-square stable for these seeds
    static = state_feedback_loop(system, gains)
    dynamic = closed_loop(system.with_measured_output(np.eye(system.dims[0])), lifted(gains, 20.0))
    a, b = mean_square_stability(static), mean_square_stability(dynamic)
    assert a.stable and b.spectral_abscissa == pytest.approx(a.spectral_abscissa, abs=1e-9)
    ra, rb = analyze(static, cross_validation=False), analyze(dynamic, cross_validation=False)
    assert ra.certified_stable and rb.certified_stable
    assert rb.nominal.gamma == pytest.approx(ra.nominal.gamma, rel=GAMMA_RTOL)
    assert rb.robust.gamma == pytest.approx(ra.robust.gamma, rel=GAMMA_RTOL)
    beta = system.chain.midpoint()
    ea, eb = exact_energy(static, beta=beta), exact_energy(dynamic, beta=beta)
    assert eb.y_energy == pytest.approx(ea.y_energy, rel=1e-9)


def test_channels_are_the_perturbed_plant(paper) -> None:
    """``A_s + sum E Delta F`` equals the loop of the plant with ``Delta`` built in."""
    system, _ = paper
    rng = np.random.default_rng(7)
    ctrl = Controller.dynamic([rng.normal(size=(2, 2)) for _ in range(2)], [rng.normal(size=(2, 1)) for _ in range(2)],
                              [rng.normal(size=(2, 2)) for _ in range(2)], [rng.normal(size=(2, 1)) for _ in range(2)])
    d1, d2 = rng.normal(size=(2, 2)), rng.normal(size=(2, 2))
    perturbed = FTCSystem(system.name, tuple(
        Mode(md.A + md.A1 @ d1 @ md.A2, md.B + md.B1 @ d2 @ md.B2, md.C, md.D) for md in system.modes), system.chain)
    loop = closed_loop(system, ctrl)
    direct = closed_loop(perturbed, ctrl)
    for got, want in zip(loop.perturbed({"Delta1 (A)": d1, "Delta2 (B)": d2}), direct.A):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert [c.name for c in loop.channels[0]] == ["Delta1 (A)", "Delta2 (B)"]


def test_observer_controller_loop_blocks(paper) -> None:
    """An observer-based controller: the (true, fdi) = (l, l) loop has the separation
    spectrum eig(A + B K) U eig(A - L Cy)."""
    import scipy.signal

    system, gains = paper
    Cy = np.array([[1.0, 2.0]])
    sys_m = system.with_measured_output(Cy)
    Ls = [scipy.signal.place_poles(md.A.T, Cy.T, [-6.0, -8.0]).gain_matrix.T for md in system.modes]
    ctrl = Controller.dynamic([md.A + md.B @ K - L @ Cy for md, K, L in zip(system.modes, gains, Ls)], Ls,
                              list(gains), [np.zeros((2, 1))] * 2)
    loop = closed_loop(sys_m, ctrl)
    for l, md in enumerate(system.modes):
        got = np.sort_complex(np.linalg.eigvals(loop.A[l * 2 + l]))
        want = np.sort_complex(np.concatenate([np.linalg.eigvals(md.A + md.B @ gains[l]), [-6.0, -8.0]]))
        np.testing.assert_allclose(got, want, atol=1e-8)


# ------------------------------------------------------------------ files

def test_controller_files_round_trip(tmp_path: Path, paper) -> None:
    system, gains = paper
    rng = np.random.default_rng(3)
    dyn = Controller.dynamic([rng.normal(size=(3, 3)) / 3 for _ in range(2)], [rng.normal(size=(3, 1)) for _ in range(2)],
                             [rng.normal(size=(2, 3)) for _ in range(2)], [rng.normal(size=(2, 1)) for _ in range(2)],
                             name="random dynamic")
    sof = Controller(tuple(np.zeros((0, 0)) for _ in range(2)), tuple(np.zeros((0, 1)) for _ in range(2)),
                     tuple(np.zeros((2, 0)) for _ in range(2)), tuple(rng.normal(size=(2, 1)) for _ in range(2)),
                     "output", "static output feedback")
    for ctrl in (Controller.state_feedback(gains, name="paper"), dyn, sof):
        path = tmp_path / "c.toml"
        save_controller(ctrl, path)
        back = load_controller(path)
        assert back == ctrl and back.name == ctrl.name and back.measures == ctrl.measures
        assert dump_controller(back) == dump_controller(ctrl)
        assert back.check(system) is back
    assert load_controller(PAPER_GAINS) == Controller.state_feedback(gains)


def test_system_file_measured_output_round_trip(tmp_path: Path, paper) -> None:
    system, _ = paper
    sys_m = system.with_measured_output(np.array([[1.0, 0.0], [0.5, 2.0]]))
    path = tmp_path / "s.toml"
    path.write_text(dump_system(sys_m))
    back = load_system(path)
    assert back == sys_m and back.ny_measured == 2 and back.has_measured_output
    assert load_system(PAPER).ny_measured == 1 and not load_system(PAPER).has_measured_output


@pytest.mark.parametrize(("text", "needles"), [
    ("[[gain]]\nK = [[1.0, 2.0]]\n[[controller]]\nDc = [[1.0]]\n", ["both [[gain]] and [[controller]]"]),
    ("[[controller]]\nAc = [[1.0]]\nBc = [[1.0]]\nCc = [[1.0], [1.0]]\nDc = [[0.0], [0.0]]\n"
     "[[controller]]\nAc = [[1.0, 0.0], [0.0, 1.0]]\nBc = [[1.0], [1.0]]\nCc = [[1.0, 0.0], [1.0, 0.0]]\n"
     "Dc = [[0.0], [0.0]]\n", ["controller[2].Ac", "expected shape 1 x 1", "got 2 x 2"]),
    ("[[controller]]\nAc = [[1.0]]\nBc = [[1.0]]\nDc = [[0.0], [0.0]]\n", ["controller[1]", "missing key", "Cc"]),
    ("[[controller]]\nDc = [[0.0], [0.0]]\n[[controller]]\nAc = [[1.0]]\nBc = [[1.0]]\nCc = [[1.0], [1.0]]\n"
     "Dc = [[0.0], [0.0]]\n", ["controller[2]", "differ from controller[1]"]),
    ("[[controller]]\nAc = [[nan]]\nBc = [[1.0]]\nCc = [[1.0], [1.0]]\nDc = [[0.0], [0.0]]\n", ["controller[1].Ac", "nan"]),
    ("[[gain]]\nK = [[1.0, 2.0]]\n[[gain]]\nK = [[1.0, 2.0, 3.0]]\n", ["gain[2].K", "differs from gain[1].K"]),
    ("name = 'x'\n", ["no [[gain]] or [[controller]]"]),
    ("[[controller]]\nAc = [[1.0]]\nBc = [[1.0]]\nCc = [[1.0], [1.0]]\nDc = [[0.0], [0.0]]\nEc = 1\n",
     ["controller[1]", "Ec"]),
])
def test_bad_controller_files(tmp_path: Path, text: str, needles: list[str]) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ProblemFileError) as info:
        load_controller(path)
    msg = str(info.value)
    assert msg.startswith(str(path)) and all(n in msg for n in needles), msg


@pytest.mark.parametrize(("ctrl", "needles"), [
    (Controller.dynamic([np.eye(1)] * 2, [np.ones((1, 2))] * 2, [np.ones((2, 1))] * 2, [np.zeros((2, 2))] * 2),
     ["2 columns", "1 measured outputs", "expected 2 x 1, got 2 x 2"]),
    (Controller.dynamic([np.eye(1)] * 3, [np.ones((1, 1))] * 3, [np.ones((2, 1))] * 3, [np.zeros((2, 1))] * 3),
     ["3 entries", "2 modes"]),
    (Controller.state_feedback([np.zeros((1, 2))] * 2), ["gain[1].K", "1 rows", "2 inputs"]),
])
def test_controller_checked_against_the_system(paper, ctrl: Controller, needles: list[str]) -> None:
    system, _ = paper
    with pytest.raises(ValidationError) as info:
        ctrl.check(system, source="my.toml")
    assert str(info.value).startswith("my.toml") and all(n in str(info.value) for n in needles), str(info.value)


def test_discretise_is_the_exact_hold_update() -> None:
    rng = np.random.default_rng(5)
    Ac, Bc = rng.normal(size=(3, 3)), rng.normal(size=(3, 2))
    ctrl = Controller.dynamic([Ac], [Bc], [np.zeros((1, 3))], [np.zeros((1, 2))])
    phi, gam = ctrl.discretise(0, 0.3)
    import scipy.integrate
    import scipy.linalg

    v = rng.normal(size=2)
    sol = scipy.integrate.solve_ivp(lambda t, z: Ac @ z + Bc @ v, (0, 0.3), np.ones(3), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(phi @ np.ones(3) + gam @ v, sol.y[:, -1], rtol=1e-8)
    np.testing.assert_allclose(phi, scipy.linalg.expm(0.3 * Ac), rtol=1e-12)
    assert math.isclose(float(np.linalg.norm(Controller.state_feedback([np.ones((1, 2))]).discretise(0, 1.0)[0])), 0.0)
