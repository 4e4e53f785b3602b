"""The readable summary of the main job: what ``ftc-verify verify`` prints.

One function, :func:`verify_summary`, used by the command line and by
``str(VerifyReport)`` (so ``print(run_verify(system))`` shows the command's summary, not
the dataclass fields). The command line adds the line naming the report's files.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .verify import VerifyReport

__all__ = ["verify_summary"]


def verify_summary(rep: VerifyReport, *, written: Sequence[Path] | None = None) -> str:
    """The summary of ``rep``, line by line as ``ftc-verify verify`` prints it.

    Parameters
    ----------
    rep : VerifyReport
        The main job's result (:func:`ftc_verify.verification.verify.run_verify`).
    written : sequence of paths, optional
        The report's files (:func:`ftc_verify.verification.report.write_report`), named
        on a ``report:`` line before the verdict; left out when ``None``.

    Returns
    -------
    str
        The lines, without a final newline; the last one is the verdict.
    """
    d = rep.to_dict()
    lines = [f"ftc-verify verify: {rep.system.name}", f"  {rep.system.chain.describe()}"]
    lines += [f"  [{'pass' if c['ok'] else 'FAIL'}] {c['name']}: {c['detail']}" for c in d["checks"]]
    risk = d.get("risk")
    if risk and not any(c["name"] == "risk" for c in d["checks"]):
        lines.append(f"  [info] risk: {risk['detail']}")
    if d["options"].get("delta"):
        lines.append(f"  Delta in the Monte Carlo: {d['options']['delta']}")
    if written is not None:
        lines.append(f"  report: {', '.join(str(p) for p in written)}")
    lines.append(f"  verdict: {d['verdict']}")
    return "\n".join(lines)
