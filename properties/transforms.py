r"""Transformations of a drawn plant + controller whose effect on the analyses is known exactly.

Each returns a new :class:`~ftc_verify.testing.DrawnLoop` rebuilt through
``FTCSystem.from_arrays`` and the :class:`~ftc_verify.controllers.Controller`
constructors (so the validation runs on the transformed data too).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ftc_verify.model.system import Matrix
from ftc_verify.testing import DrawnLoop

__all__ = ["similarity", "controller_similarity", "relabel", "scale_disturbance", "with_beta_box"]


def similarity(drawn: DrawnLoop, T: Matrix) -> DrawnLoop:
    r"""Plant state change :math:`\tilde x = T x`.

    :math:`\tilde A = T A T^{-1}`, :math:`\tilde B = T B`, :math:`\tilde C = C T^{-1}`,
    :math:`\tilde C_y = C_y T^{-1}`, :math:`\tilde D = T D`, :math:`\tilde A_1 = T A_1`,
    :math:`\tilde A_2 = A_2 T^{-1}`, :math:`\tilde B_1 = T B_1`, :math:`\tilde B_2 = B_2`
    (it acts on ``u``); a controller reading the state gets
    :math:`\tilde K = K T^{-1}` (:math:`\tilde B_c = B_c T^{-1}`), one reading ``y_m`` is unchanged.
    """
    Ti = np.linalg.inv(T)
    spec = drawn.spec()
    right = {"A": (T, Ti), "B": (T, None), "C": (None, Ti), "Cy": (None, Ti), "D": (T, None),
             "A1": (T, None), "A2": (None, Ti), "B1": (T, None), "B2": (None, None)}
    for md in spec["modes"]:
        for key, (left, rgt) in right.items():
            if key in md:
                M = md[key]
                if left is not None:
                    M = left @ M
                if rgt is not None:
                    M = M @ rgt
                md[key] = M
    if "gains" in spec:
        spec["gains"] = [K @ Ti for K in spec["gains"]]
    elif drawn.controller.measures == "state":
        spec["dynamic"]["Bc"] = [B @ Ti for B in spec["dynamic"]["Bc"]]
        spec["dynamic"]["Dc"] = [D @ Ti for D in spec["dynamic"]["Dc"]]
    return DrawnLoop.from_spec(**spec)


def controller_similarity(drawn: DrawnLoop, T: Matrix) -> DrawnLoop:
    r"""Controller state change :math:`\tilde x_c = T x_c` of a dynamic controller:
    :math:`\tilde A_c = T A_c T^{-1}`, :math:`\tilde B_c = T B_c`,
    :math:`\tilde C_c = C_c T^{-1}`, :math:`\tilde D_c = D_c` in every FDI mode."""
    Ti = np.linalg.inv(T)
    spec = drawn.spec()
    dyn = spec["dynamic"]
    dyn["Ac"] = [T @ A @ Ti for A in dyn["Ac"]]
    dyn["Bc"] = [T @ B for B in dyn["Bc"]]
    dyn["Cc"] = [C @ Ti for C in dyn["Cc"]]
    return DrawnLoop.from_spec(**spec)


def relabel(drawn: DrawnLoop, perm: Sequence[int]) -> DrawnLoop:
    """Rename the fault modes: new mode ``k`` is old mode ``perm[k]`` (plant tables,
    rows and columns of ``alpha``, ``beta_min``, ``beta_max``, and the controller's
    FDI-mode entries)."""
    p = np.asarray(perm, dtype=int)
    spec: dict[str, Any] = drawn.spec()
    spec["modes"] = [spec["modes"][k] for k in p]
    for key in ("alpha", "beta_min", "beta_max"):
        spec[key] = spec[key][np.ix_(p, p)]
    if "gains" in spec:
        spec["gains"] = [spec["gains"][k] for k in p]
    else:
        spec["dynamic"] = {key: [v[k] for k in p] for key, v in spec["dynamic"].items()}
    return DrawnLoop.from_spec(**spec)


def scale_disturbance(drawn: DrawnLoop, c: float) -> DrawnLoop:
    """Every disturbance matrix ``D_i`` multiplied by ``c``."""
    spec = drawn.spec()
    for md in spec["modes"]:
        md["D"] = c * md["D"]
    return DrawnLoop.from_spec(**spec)


def with_beta_box(drawn: DrawnLoop, beta_min: Matrix, beta_max: Matrix) -> DrawnLoop:
    """The same plant and controller with another detection-rate box."""
    spec = drawn.spec()
    spec["beta_min"], spec["beta_max"] = np.array(beta_min, dtype=float), np.array(beta_max, dtype=float)
    return DrawnLoop.from_spec(**spec)
