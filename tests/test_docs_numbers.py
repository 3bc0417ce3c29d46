"""The numbers the docs quote for shipped scenarios, checked against fresh full-length runs.

docs/scenarios.md's key-metrics table: each row is run at full length and each number must equal the
run's value to the digits printed (|quoted - measured| <= half a unit of the last printed digit); a
value below 1e-12 is "exact to rounding" (the bits there are the platform's, not the law's).
docs/physical-loop.md's output-feedback figures: each quoted text must be in the page and match its run.
"""

import re
from pathlib import Path

import pytest

from ftstab_mj import api

DOCS = Path(__file__).resolve().parent.parent / "docs"
NUMBER = re.compile(r"[-+]?\d+(?:\.(\d+))?(?:e([-+]?\d+))?")


def _matches(quoted: str, value) -> bool:
    """Whether ``value`` rounds to ``quoted`` (half a unit of the quoted number's last digit)."""
    m = NUMBER.fullmatch(quoted)
    assert m, quoted
    q = float(quoted)
    decimals = len(m.group(1) or "") - int(m.group(2) or 0)
    if abs(q) < 1e-12:
        return value is not None and abs(value) < 1e-12
    return value is not None and abs(value - q) <= 0.5 * 10.0 ** -decimals * (1 + 1e-9)


def _table_rows():
    rows = []
    for line in (DOCS / "scenarios.md").read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 8 and re.match(r"[a-z]\w+", cells[0]) and cells[0] != "scenario":
            rows.append(cells)
    return rows


def _values(cell: str) -> list[str]:
    """The numbers of a cell, one per loop ("1.90 / 1.82 s" -> ["1.90", "1.82"]); "" for an empty cell."""
    cell = re.sub(r"\(first entry\)|\(= eps\)|held|[()]|\b(s|m|rad)\b", "", cell)
    return [p.strip() for p in cell.split("/")] if cell.strip() else []


ROWS = _table_rows()


def test_the_table_is_found():
    assert len(ROWS) >= 12


@pytest.mark.parametrize("cells", ROWS, ids=[r[0].split()[0].rstrip(",") for r in ROWS])
def test_scenario_table_row_matches_a_fresh_run(cells):
    name = cells[0].split()[0].rstrip(",")
    res = api.run(name, keep_samples=False)
    loops = list(res.metrics["loops"].values())
    adaptive = "first entry" in cells[3] or cells[1] == "adaptive"
    columns = {  # column -> metric of each loop
        3: lambda m: m["eps_entry_time"] if "first entry" in cells[3] else m["settle_time"],
        4: lambda m: m["time_bound"],
        5: lambda m: m["final_abs_z_max"][0],
        6: lambda m: m["u_max_abs"],
        7: lambda m: (m["theorem3"] or {}).get("Delta"),
    }
    for col, metric in columns.items():
        quoted = _values(cells[col])
        if col == 4 and adaptive:
            continue
        for i, q in enumerate(quoted):
            got = metric(loops[i])
            ok = got is None if q == "never" else _matches(q, got)
            assert ok, f"{name}, column {col} loop {i}: docs say {q}, a fresh run gives {got}"


# physical-loop.md: (quoted text, scenario, overrides, metric values the text's numbers must match)
PHYSICAL = [
    ("final abs x 6.2e-4 m; with position noise 1e-3 / 3e-3 / 1e-2 m: 1.4e-2 / 2.1e-2 / 6.7e-2 m",
     "cart_r3_output_feedback", [None, "1e-3", "3e-3", "1e-2"], ["6.2e-4", "1.4e-2", "2.1e-2", "6.7e-2"]),
]


@pytest.mark.parametrize("text, name, noises, quoted", PHYSICAL)
def test_physical_loop_figures_match_fresh_runs(text, name, noises, quoted):
    assert text in (DOCS / "physical-loop.md").read_text()
    for noise, q in zip(noises, quoted):
        over = [] if noise is None else [f"loops.cart.sensor.noise={noise}"]
        got = api.run(name, overrides=over, keep_samples=False).metrics["loops"]["cart"]["final_abs_z_max"][0]
        assert _matches(q, got), f"{name} noise {noise}: docs say {q}, a fresh run gives {got}"
