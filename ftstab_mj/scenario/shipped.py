"""The scenarios shipped in the repository's scenarios/ directory, and finding one by name."""

from __future__ import annotations

import tomllib
from pathlib import Path

from ftstab_mj.config.resources import data_dir

SCENARIO_DIR = data_dir("scenarios")


def shipped_scenarios() -> list[tuple[str, Path, str]]:
    """(name, path, one-line description) of every scenarios/*.toml, sorted by file name."""
    rows = []
    for path in sorted(SCENARIO_DIR.glob("*.toml")):
        try:
            raw = tomllib.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
            rows.append((path.stem, path, f"(unreadable: {exc})"))
            continue
        rows.append((str(raw.get("name", path.stem)), path, str(raw.get("description", "(no description)"))))
    return rows


def find_scenario(arg: str, folder: Path = SCENARIO_DIR) -> Path:
    """``arg`` as a path if it names an existing file or looks like one, else scenarios/<arg>.toml
    (``folder``/<arg>.toml)."""
    path = Path(arg)
    if path.exists() or path.suffix or "/" in arg:
        return path
    shipped = folder / f"{arg}.toml"
    return shipped if shipped.exists() else path


def find_sweep(arg: str) -> Path:
    """``arg`` as a path, else the shipped sweep scenarios/sweeps/<arg>.toml (as ``ftstab run`` finds a scenario)."""
    return find_scenario(arg, SCENARIO_DIR / "sweeps")
