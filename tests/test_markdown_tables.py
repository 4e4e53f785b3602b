"""Markdown tables keep every cell: a ``|`` inside a cell (``E||y||^2``) is escaped.

Unescaped, such a ``|`` ends the cell when the table renders and the number after it
vanishes (issue 33): the report's "exact energy" row showed "max E" and the Numbers
table's exact-energy value was empty. ``report.md`` is parsed back with markdown-it (the
parser of myst-parser, which the documentation site uses) and its numbers are found in
the right cells; every table of the documentation pages is checked the same way.
"""

from __future__ import annotations

import re
from pathlib import Path

import markdown_it

from ftc_verify.model.files import load_system
from ftc_verify.verification.montecarlo import MCEstimate
from ftc_verify.verification.report import render_markdown, table_row
from ftc_verify.verification.verify import Check, VerifyReport

ROOT = Path(__file__).resolve().parents[1]


def _parser() -> markdown_it.MarkdownIt:
    return markdown_it.MarkdownIt("commonmark").enable("table")


def tables(text: str) -> list[list[list[str]]]:
    """Every table of a markdown text as rendered: rows of cell texts (code spans kept)."""
    out: list[list[list[str]]] = []
    inside = False
    for token in _parser().parse(text):
        if token.type in ("table_open", "table_close"):
            inside = token.type == "table_open"
            out += [[]] if inside else []
        elif token.type == "tr_open":
            out[-1].append([])
        elif token.type == "inline" and inside:
            out[-1][-1].append("".join(child.content for child in token.children or []))
    return out


def _report() -> VerifyReport:
    system = load_system(ROOT / "examples" / "paper.toml")
    mc = MCEstimate(paths=200, seed=1, alpha=1e-6, mean_energy=0.5, std_energy=0.1, w_energy=10.0,
                    mean_ratio=0.0508641, lower_bound=0.044, upper_bound=0.0574662, gamma=0.360844,
                    event_fraction=None, event_interval=None)
    checks = (
        Check("certified", True, "robust gamma 0.360844 (Lemma 4.1), spectral abscissa -0.9816"),
        Check("exact energy", True, "max E||y||^2/||w||^2 = 0.0547037 (Delta=-E) vs gamma^2 = 0.130209"),
        Check("region", False, "2 of 5 paths left [region]; inputs within [[-1.5], [2.5]] | clipped"),
    )
    plant = {"fmu": "Motor.fmu", "model_identifier": "Motor", "measure": "incremental", "mean_ratio": 2.68e-6,
             "upper_bound": 2.69e-6, "max_excursion": [0.12345678901234, 0.2], "linearisation_error": 0.0123,
             "input_range": [[-1.5], [2.5]], "left_region": 2, "paths": 5, "fault_response_energy": 3.25e-3}
    return VerifyReport(system=system, controller=None, gamma_certified=0.360844, analysis=None, synthesis=None,
                        per_mode=(), exact=({"ratio": 0.0547037},), mc=mc, records=(), checks=checks,
                        seed=1, options={"fdi_model": "FDI: exponential detection delays"}, plant=plant)


def test_table_row_escapes_every_pipe_and_line_break() -> None:
    row = table_row("a|b", "E||y||\nnext", 3)
    assert row == r"| a\|b | E\|\|y\|\| next | 3 |"
    assert tables(f"| x | y | z |\n|---|---|---|\n{row}\n") == [[["x", "y", "z"], ["a|b", "E||y|| next", "3"]]]


def test_report_md_parsed_back_keeps_its_numbers() -> None:
    md = render_markdown(_report())
    parsed = tables(md)
    assert len(parsed) == 3, md  # checks, Numbers, Plant
    for table in parsed:
        width = len(table[0])
        assert all(len(row) == width for row in table), table
    checks = {row[0]: row[1:] for row in parsed[0][1:]}
    assert checks["exact energy"] == ["pass", "max E||y||^2/||w||^2 = 0.0547037 (Delta=-E) vs gamma^2 = 0.130209"]
    assert checks["region"] == ["FAIL", "2 of 5 paths left [region]; inputs within [[-1.5], [2.5]] | clipped"]
    numbers = {row[0]: row[1] for row in parsed[1][1:]}
    assert numbers["exact E||y||^2/||w||^2, worst case over beta vertices and Delta"] == "0.0547037"
    assert numbers["Monte Carlo one-sided upper bound (alpha 1e-6)"] == "0.0574662"
    plant = {row[0]: row[1] for row in parsed[2][1:]}
    assert plant["attenuation on the plant: mean E||y - y_op||^2/||w||^2 of y(w) - y(w = 0)"] == "2.68e-06"
    assert plant["fault response: mean ||y(w = 0) - y_op||^2 (not bounded by gamma)"] == "0.00325"
    assert plant["largest excursion from the operating point, per state"] == "[0.1235, 0.2]"
    assert plant["inputs: smallest and largest value, per input (absolute)"] == "[[-1.5], [2.5]]"


def _markdown_pages() -> list[Path]:
    pages = [p for p in (ROOT / "docs").rglob("*.md") if "_build" not in p.parts]
    return sorted(pages + [ROOT / "README.md", *ROOT.glob("*/README.md"), *(ROOT / "examples").rglob("*.md")])


def test_every_table_row_of_the_pages_has_the_header_width() -> None:
    """A row with more source cells than its header lost the rest when rendered."""
    bad = []
    for page in _markdown_pages():
        lines = page.read_text(encoding="utf-8").splitlines()
        width = 0
        for token in _parser().parse("\n".join(lines)):
            if token.type == "table_open":
                width = 0
            elif token.type == "tr_open" and token.map is not None:
                source = lines[token.map[0]].strip().removeprefix("|").removesuffix("|")
                cells = len(re.split(r"(?<!\\)\|", source))
                width = width or cells
                if cells != width:
                    bad.append(f"{page.relative_to(ROOT)}:{token.map[0] + 1}: {cells} cells, header {width}")
    assert bad == [], "a '|' inside a table cell must be written '\\|':\n" + "\n".join(bad)


def test_three_tank_attenuation_row_renders_its_number() -> None:
    text = (ROOT / "docs" / "tutorials" / "three-tank.md").read_text(encoding="utf-8")
    rows = [row for table in tables(text) for row in table if row[0].startswith("attenuation on the nonlinear FMU")]
    found = re.match(r"([0-9.]+e-[0-9]+) \(upper bound ([0-9.]+e-[0-9]+), alpha 1e-6\)$", rows[0][1]) if len(rows) == 1 else None
    assert found is not None, rows
    assert float(found.group(1)) <= float(found.group(2)), rows  # the mean below its one-sided upper bound
