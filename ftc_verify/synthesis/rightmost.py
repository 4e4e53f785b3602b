r"""The rightmost eigenvalue of a real matrix and its left and right eigenvectors, straight
from LAPACK's ``geev`` (:func:`rightmost`).

The descent of :mod:`ftc_verify.synthesis.descent` asks for the rightmost eigenvalue
:math:`\lambda` of the second-moment generator :math:`\mathcal L` (order 40 for the paper's
plant with a controller of order 2) thousands of times, and for its eigenvectors
:math:`u, v` (:math:`u^H \mathcal L = \lambda u^H`, :math:`\mathcal L v = \lambda v`) at
the worst vertex only. ``scipy.linalg.eig`` gives every eigenvector as a complex column
(real ``geev`` returns a conjugate pair :math:`\lambda, \bar\lambda` as the two real
columns :math:`a, b` of :math:`v = a \pm i b`) and asks LAPACK for its workspace on every
call; here the workspace is asked once per order and only the one column is rebuilt, by
the same arithmetic, so the numbers are those of ``scipy.linalg.eig`` bit for bit (the
same routine, workspace and input). Without eigenvectors ``geev`` does about half the
work; its eigenvalues are the same numbers (the QR iteration on the active block does not
depend on whether the Schur vectors are accumulated).
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from ..model.system import Matrix

__all__ = ["rightmost"]


@functools.lru_cache(maxsize=64)
def _geev(n: int, vectors: bool) -> tuple[Any, int]:
    """LAPACK's real ``geev`` and the workspace ``scipy.linalg.eig`` gives it for order
    ``n`` (its workspace query, asked once per size: the same ``lwork``, so the same
    blocking and the same numbers as ``scipy.linalg.eig``)."""
    from scipy.linalg import lapack

    geev, geev_lwork = lapack.get_lapack_funcs(("geev", "geev_lwork"), (np.zeros((1, 1)),))
    work, info = geev_lwork(n, compute_vl=int(vectors), compute_vr=int(vectors))
    if info != 0:
        raise ValueError(f"geev workspace query failed: {info}")
    return geev, int(work.real)


def rightmost(G: Matrix, vectors: bool) -> tuple[float, Matrix | None, Matrix | None] | None:
    """``(Re lambda, u, v)`` of the rightmost eigenvalue of ``G`` (left and right
    eigenvectors when ``vectors``) straight from LAPACK's ``geev`` -- exactly the numbers
    of ``scipy.linalg.eig`` (same routine and workspace; its complex eigenvectors are
    ``vr[:, k] +- i vr[:, k + 1]`` for a conjugate pair, rebuilt here for the one column
    needed instead of for all). ``None`` (the caller then asks ``scipy.linalg.eig``) when
    ``G`` is not a finite float64 matrix, LAPACK reports a failure, or the pairs are not
    in LAPACK's documented order."""
    if G.dtype != np.float64 or not np.all(np.isfinite(G)):
        return None
    geev, lwork = _geev(G.shape[0], vectors)
    wr, wi, vl, vr, info = geev(G, lwork=lwork, compute_vl=int(vectors), compute_vr=int(vectors))
    if info != 0:
        return None
    k = int(np.argmax(wr))
    if not vectors:
        return float(wr[k]), None, None
    if np.all(wi == 0.0):
        return float(wr[k]), vl[:, k], vr[:, k]
    first = wi > 0  # the first column of each conjugate pair (as scipy.linalg.eig marks them)
    first[:-1] |= wi[1:] < 0
    if np.any(first[:-1] & first[1:]):
        return None
    out = []
    for vin in (vl, vr):  # the parts written as scipy writes them (no arithmetic: signed zeros kept)
        col = np.zeros(vin.shape[0], dtype=complex)
        if first[k]:
            col.real, col.imag = vin[:, k], vin[:, k + 1]
        elif k > 0 and first[k - 1]:
            col.real, col.imag = vin[:, k - 1], -vin[:, k]
        else:
            col.real = vin[:, k]
        out.append(col)
    return float(wr[k]), out[0], out[1]
