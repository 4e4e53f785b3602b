from hypothesis import given
from ftc_verify.analysis import analyze, closed_loop
from ftc_verify.synthesis import synthesize
from ftc_verify.testing import profile, systems
from ftc_verify.analysis.moments.energy import exact_energy

def my_design(system):  # your design function; here the "common" LMI synthesis
    return synthesize(system, method="common", k_max=20.0).controller

@profile("ci", max_examples=5)
@given(systems(n=2, m=2, stability_margin=0.2, uncertain=None))
def test_my_design_is_stable_and_its_gamma_bounds_the_energy(system):
    loop = closed_loop(system, my_design(system))
    report = analyze(loop)  # exact mean-square stability test + certified gammas
    assert report.certified_stable and report.robust.certified
    for beta in system.chain.vertices():  # exact expected energy of the paper's disturbance
        assert exact_energy(loop, beta=beta).ratio <= report.robust.gamma ** 2 * (1 + 1e-6)
