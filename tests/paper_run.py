"""The options of the ``verify`` run of the paper's plant and gains that several CLI tests
read (the session fixture ``paper_verify_run`` of ``tests/conftest.py``).

A module of its own, not ``conftest``: test modules whose functions Dask workers unpickle
(``test_cluster.py``) are imported again in the workers, where ``import conftest`` finds
the repository root's ``conftest.py`` first.
"""

PAPER_VERIFY_OPTIONS = ("--paths", "30", "--horizon", "15", "--step", "0.01", "--seed", "3")
