r"""Lemma 4.1's program with the uncertainty channels that share an input matrix merged.

In the block of Lemma 4.1 (:func:`~ftc_verify.analysis.lmi.lyapunov_block`) every channel
:math:`(E_k, F_k)` of joint state :math:`s` has its own border :math:`P_s E_k` and
diagonal :math:`-\lambda_k I`, so the block has :math:`n + \sum_k \operatorname{cols}(E_k)
+ n_w + n_z` rows. When the channels of a group share their input matrix up to a scale,
:math:`E_k = c_k \bar E` (the paper's model: :math:`A_1 = B_1 = 0.1 I`; the random loops of
``benchmarks/scaling.py``: :math:`0.05 I`), one border suffices, and the program keeps
the same feasible set in :math:`(P, \lambda, g)`.

**Derivation.** With the solver's margin :math:`t` (``block + t I <= 0``; :math:`t` fixed
or a variable, :mod:`ftc_verify.analysis.lmi_analysis`), the Schur complement on the
:math:`-(\lambda_k - t) I` rows turns the group's borders into
:math:`\sum_k c_k^2 (\lambda_k - t)^{-1} P \bar E \bar E^T P`. Replace them by one border
:math:`P \bar E` with diagonal :math:`-\mu I` (so :math:`-(\mu - t) I` with the margin) and
require

.. math::

    \frac{1}{\mu - t} \ge \sum_k \frac{c_k^2}{\lambda_k - t}
    \iff \exists \sigma_k:\;
    \begin{bmatrix} \sigma_k & c_k (\mu - t) \\ c_k (\mu - t) & \lambda_k - t \end{bmatrix} \succeq 0,
    \quad \sum_k \sigma_k \le \mu - t ,

(the 2 x 2 cone says :math:`\sigma_k (\lambda_k - t) \ge c_k^2 (\mu - t)^2`; summing,
:math:`(\mu - t)^2 \sum_k c_k^2/(\lambda_k - t) \le \mu - t`). The merged block with
these cones implies the full one (its Schur complement is at least as negative), and every
feasible point of the full one gives a feasible point of the merged one
(:math:`\mu - t = 1/\sum_k c_k^2/(\lambda_k - t)`, :math:`\sigma_k = c_k^2 (\mu - t)^2 /
(\lambda_k - t)`): the same program, with blocks smaller by
:math:`(\text{members} - 1) \operatorname{cols}(\bar E)` rows each (n = 12, two channels of
12 columns: 39 -> 27), for one 2 x 2 cone per channel and one row per group. The :math:`\lambda_k` stay
variables; the certificate is proved on the full blocks with them
(:func:`~ftc_verify.analysis.lmi.check_certificate`), so nothing here is trusted.

In the loop handed to the block builder (:func:`merged_loop`) a member keeps its
:math:`F_k` (the term :math:`\lambda_k F_k^T F_k`) with an :math:`E` of no columns, and the
group's :math:`\bar E` is a channel of its own with an :math:`F` of no rows, whose
multiplier is :math:`\mu`, appended after the state's channels.

The extra cones can be badly scaled (one tiny multiplier makes :math:`\sigma_k` and
:math:`\mu` tiny): :func:`merged_first` solves the full program too when the merged one
does not end cleanly, and keeps the smaller certified gamma.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from .closedloop import Channel, ClosedLoop
from .conic import Affine, Rows

__all__ = ["ChannelGroup", "RTOL", "shared_input_groups", "merged_loop", "group_cones", "merged_first"]

#: Channels are merged when ``||E_k - c_k E_first||_F <= RTOL ||E_k||_F``.
RTOL = 1e-13


@dataclass(frozen=True)
class ChannelGroup:
    """Channels ``members`` (indices into ``loop.channels[s]``, at least two) of joint
    state ``s`` with ``E_k = scales[k] * E`` of the first member (``scales[0] = 1``)."""

    s: int
    members: tuple[int, ...]
    scales: tuple[float, ...]


def shared_input_groups(loop: ClosedLoop) -> tuple[ChannelGroup, ...]:
    """Every group of two or more channels of one joint state whose ``E`` are multiples of
    the group's first (up to :data:`RTOL`), in state and channel order."""
    groups = []
    for s, chans in enumerate(loop.channels):
        taken: set[int] = set()
        for j, lead in enumerate(chans):
            norm = float(np.sum(lead.E * lead.E))
            if j in taken or norm == 0.0:
                continue
            members, scales = [j], [1.0]
            for k in range(j + 1, len(chans)):
                E = chans[k].E
                if k in taken or E.shape != lead.E.shape:
                    continue
                c = float(np.sum(E * lead.E)) / norm
                if c != 0.0 and np.linalg.norm(E - c * lead.E) <= RTOL * np.linalg.norm(E):
                    members.append(k)
                    scales.append(c)
            if len(members) > 1:
                taken.update(members)
                groups.append(ChannelGroup(s, tuple(members), tuple(scales)))
    return tuple(groups)


def merged_loop(loop: ClosedLoop, groups: tuple[ChannelGroup, ...]) -> ClosedLoop:
    """The loop whose blocks are the merged ones (module docstring): each member's ``E``
    with no columns, and per group a channel ``(E_first, no rows)`` appended after the
    state's channels, in group order."""
    if not groups:
        return loop
    channels = [list(chans) for chans in loop.channels]
    for group in groups:
        chans = loop.channels[group.s]
        for k in group.members:
            channels[group.s][k] = Channel(np.zeros((loop.n, 0)), chans[k].F, chans[k].name)
        lead = chans[group.members[0]]
        channels[group.s].append(Channel(lead.E, np.zeros((0, loop.n)), f"{lead.name}+shared"))
    return dataclasses.replace(loop, channels=tuple(tuple(c) for c in channels))


def group_cones(rows: Rows, groups: tuple[ChannelGroup, ...], lam_start: tuple[int, ...],
                channels: tuple[int, ...], t: int, first_sigma: int) -> None:
    r"""Add the cones of the module docstring: for every member :math:`k` of every group
    the 2 x 2 cone in :math:`(\sigma_k, \mu, t, \lambda_k)` and the row
    :math:`\mu - t - \sum_k \sigma_k \ge 0`. ``lam_start[s]``: the column of the first
    multiplier of state ``s``, ``channels[s]``: the number of the state's channels before
    the groups' ``mu`` (appended in group order), ``t``: the margin's column, the
    :math:`\sigma` from column ``first_sigma`` on, in member order."""
    sigma = first_sigma
    seen: dict[int, int] = {}
    for group in groups:
        mu = lam_start[group.s] + channels[group.s] + seen.get(group.s, 0)
        seen[group.s] = seen.get(group.s, 0) + 1
        total = np.zeros((1, rows.K))
        total[0, mu], total[0, t] = -1.0, 1.0
        for k, c in zip(group.members, group.scales):
            lin = np.zeros((2, 2, 4))  # local variables: sigma_k, mu, t, lambda_k; -[[s, c (mu - t)], [., l - t]]
            lin[0, 0, 0] = -1.0
            lin[0, 1] = lin[1, 0] = (0.0, -c, c, 0.0)
            lin[1, 1] = (0.0, 0.0, 1.0, -1.0)
            rows.lmi(Affine(np.zeros((2, 2)), lin), np.array([sigma, mu, t, lam_start[group.s] + k]))
            total[0, sigma] = 1.0
            sigma += 1
        rows.nonneg(total, [0.0])


def merged_first(solve: Callable[[bool, list[bool]], Any], groups: bool) -> Any:
    """``solve(merge, ended)`` returns a certified ``LMIResult`` or ``None``, and appends
    ``True`` to ``ended`` when the solver ended cleanly (``optimal`` near its dual bound).
    The merged program first; when there are ``groups`` to merge and it did not end
    cleanly, the full program too, and the smaller certified gamma of the two (the same
    feasible set, but the merged program's extra cones can be badly scaled: the paper's
    loop designed with unbounded gains (``synthesize --method common``, ``k_max = 1e300``)
    gave 0.001494, ``optimal_inaccurate``, where the full program gives 0.001008)."""
    ended: list[bool] = []
    merged = solve(True, ended)
    if ended or not groups:
        return merged
    full = solve(False, [])
    found = [r for r in (merged, full) if r is not None and r.gamma is not None]
    return min(found, key=lambda r: r.gamma) if found else None
