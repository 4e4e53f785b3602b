"""The readable summary of an analysis: what ``ftc-verify analyze`` prints.

One function, :func:`analysis_summary`, used by the command line and by
``str(AnalysisReport)`` (so ``print(analyze(loop))`` in Python shows the same table as
the command, not the dataclass fields). The command line adds the FDI model's line,
which the report does not hold.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ..claimtext import lower_text, upper_text

if TYPE_CHECKING:
    from .analyze import AnalysisReport

__all__ = ["analysis_summary"]


def _num(x: float | None) -> str:
    return "-" if x is None else f"{x:.6g}"


def analysis_summary(rep: AnalysisReport, *, fdi_model: str | None = None) -> str:
    """The summary of ``rep``, line by line as ``ftc-verify analyze`` prints it.

    Parameters
    ----------
    rep : AnalysisReport
        The analysis (:func:`ftc_verify.analysis.analyze.analyze`). Whether the LMIs were
        requested is read from it (their outcome ``"not requested"``).
    fdi_model : str, optional
        The FDI model's description (``system.chain.describe()``), printed as the second
        line; left out when ``None``.

    Returns
    -------
    str
        The lines, without a final newline; the last one is the verdict.
    """
    d = rep.to_dict()
    mss = d["mss"]
    lmi = rep.mes_lmi.outcome != "not requested"
    vert = (f"float estimate, worst of {mss['vertices_evaluated']} rate vertices"
            + ("" if mss["exhaustive"] else ", greedy search") + (" and the witness" if mss["witness"] else ""))
    lines = [f"ftc-verify analyze: {rep.name} ({rep.controller})"] + ([f"  {fdi_model}"] if fdi_model else [])
    word = {"stable": "stable", "not stable": "NOT stable", "undecided": "UNDECIDED"}[mss["verdict"]]
    if mss["spectral_abscissa_contradicted"]:
        vert += "; contradicted by the proof: float64 cannot resolve this realisation"
    lines += [f"  mean-square stability    spectral abscissa {_num(mss['spectral_abscissa'])} ({vert}): {word}",
              f"      proved: {mss['verified_by']}"]
    if not lmi:
        lines.append("  LMI certificates         not requested (--no-lmi)")
    for label, res in (("Theorem 3.1 LMI", rep.mes_lmi), ("nominal gamma (Th. 3.2)", rep.nominal),
                       ("robust gamma (Lem. 4.1)", rep.robust)) if lmi else ():
        value = "" if res.gamma is None or label.startswith("Theorem") else f"{upper_text(res.gamma)}  "
        status = res.outcome + (f" ({res.solver}, status {res.solver_status})" if res.solver else "")
        lines.append(f"  {label:<24} {value}{status}")
        if not res.certified and res.message:
            lines.append(f"      {res.message}")
        low = None if label.startswith("Theorem") else d["hinf"][
            "nominal_lower_bound" if label.startswith("nominal") else "robust_lower_bound"]
        if low is not None:
            lines.append(f"      {_bracket_text(low)}")
    lines.append("  per joint mode (true, fdi): frozen poles, H-inf norm, python-control")
    for m in rep.per_mode:
        poles = ", ".join(f"{p.real:.4g}{p.imag:+.4g}j" if abs(p.imag) > 1e-12 else f"{p.real:.4g}" for p in m.poles)
        norm = (f"{m.hinf_norm:.6g}" if m.hinf_norm != float("inf") else "inf (unstable)" if not m.stable
                else "inf (float64: j omega I - A singular)")
        lines.append(f"    ({m.true_mode}, {m.fdi_mode})  poles [{poles}]  norm {norm}  {m.detail}")
    if rep.certified_stable:
        verdict = "certified stable"
    elif rep.mss.stable and not lmi:
        return "\n".join(lines + ["  verdict: stable by the exact spectral test (LMI certificates not requested: "
                                  "--no-lmi)"])
    elif rep.mss.stable:
        verdict = "stable by the exact spectral test, but NO LMI certificate found (not a proof either way)"
    elif rep.mss.undecided:
        verdict = ("UNDECIDED: neither stability nor instability could be proved over the whole rate box "
                   f"({rep.mss.reason})")
    else:
        verdict = "NOT stable (proved at a rate vector of the box)"
    lines.append(f"  verdict: {verdict}; certificates {'all passed' if rep.certificate_ok else 'NOT all passed'}")
    return "\n".join(lines)


def _bracket_text(low: dict[str, Any]) -> str:
    """One line: the proved lower bound beside a certified gamma."""
    if low["estimate"] is None:  # not computed (lower_bound.gain_lower_bound)
        return f"lower bound: none ({low['method']})"
    where = f"{low['delta']}, rates {low['rates']}, w = F x + e cos({low['frequency']:.4g} t)"
    if low["value"] is None:
        return f"lower bound: none proved ({low['method']}); float estimate {low['estimate']:.6g} at {where}"
    ratio = "" if low["ratio"] is None else f"; certified / lower = {low['ratio']:.6g}"
    flag = " (LOOSE: above 1.05)" if low["loose"] else ""
    return f"proved lower bound {lower_text(low['value'])} at {where}{ratio}{flag}"
