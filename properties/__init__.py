"""Hypothesis property tests of the ftc_verify core (run: ``pytest properties``)."""
