"""The exact second-moment machinery, one home for analysis and verification.

Continuous time: the second-moment generator of the joint chain, its spectral abscissa and
the box verdict (:mod:`.stability`), the matrix-free spectral test for large loops
(:mod:`.matrix_free`), the exact expected output energy and the worst-case disturbance of
the moment equations (:mod:`.energy`). Sampled data: the one-period map of the loop with a
sample-and-hold controller, its spectral radius and ``h_max`` (:mod:`.sampled`), their
ball-arithmetic proofs over the rate box (:mod:`.sampled_proof`, :mod:`.sampled_balls`)
the sampled loop's exact expected energy (:mod:`.sampled_energy`) and its proved L2 gain
(:mod:`.sampled_gamma`).

Monte Carlo energies of simulated paths are not here: they belong to the simulators
(:mod:`ftc_verify.simulation.vectorised`).
"""

__all__: list[str] = []
