"""docs/compare.md's validation table (per law: the source's claim, our measurement, the tests): every
registered law of the package has a row, and every test it names is a test function of this suite (so a
new law cannot skip the table, nor a renamed test leave it pointing at nothing)."""

import ast
import re
from pathlib import Path

import ftstab_mj.control.laws  # noqa: F401  (registers the shipped laws)
from ftstab_mj.control.law import LAWS

ROOT = Path(__file__).resolve().parent.parent
HEADING = "## Validation against the sources"


def _rows() -> dict[str, list[str]]:
    """{law: [test names]} from the table under HEADING (rows "| `law` | source | claim | measured | tests |")."""
    text = (ROOT / "docs" / "compare.md").read_text()
    assert HEADING in text
    section = text.split(HEADING, 1)[1].split("\n## ", 1)[0]
    rows = {}
    for line in section.splitlines():
        cells = [c.strip() for c in re.split(r"(?<!\\)\|", line.strip())[1:-1]]
        m = re.fullmatch(r"`(\w+)`", cells[0]) if len(cells) == 5 else None
        if m:
            assert m.group(1) not in rows, f"two rows for {m.group(1)}"
            assert all(cells[1:4]), f"{m.group(1)}: an empty source, claim or measurement"
            rows[m.group(1)] = re.findall(r"`(test_\w+)`", cells[4])
    return rows


def _test_functions() -> set[str]:
    names = set()
    for path in (ROOT / "tests").glob("test_*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef) and node.name.startswith("test_"):
                names.add(node.name)
    return names


def test_every_registered_law_has_a_validation_row():
    shipped = {name for name, cls in LAWS.items() if cls.__module__.startswith("ftstab_mj.")}
    rows = _rows()
    assert len(shipped) >= 14
    assert set(rows) == shipped, (sorted(shipped - set(rows)), sorted(set(rows) - shipped))


def test_every_test_the_table_names_exists():
    defined = _test_functions()
    for law, tests in _rows().items():
        assert tests, f"{law}: no test named"
        missing = [t for t in tests if t not in defined]
        assert not missing, f"{law}: {missing}"
