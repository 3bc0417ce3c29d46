"""Reading a TOML input file (scenario, sweep, expectations) with the project's one-line errors.

Every failure names the file, a key path ("(file)" for the file itself, "(TOML syntax)" for a parse
error), what was expected and what was found, through the caller's ScenarioError subclass.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

from ftstab_mj.errors import ScenarioError


def read_toml(path, kind: str, error: type[ScenarioError] = ScenarioError) -> dict:
    """The table of the TOML file ``path``; ``kind`` names it in errors (e.g. "scenario file (.toml)")."""
    src, p = str(path), Path(path)
    if not p.is_file():
        raise error(src, "(file)", f"an existing {kind}", "a directory" if p.is_dir() else "no such file")
    try:
        return tomllib.loads(p.read_text(encoding="utf-8"))
    except OSError as exc:
        raise error(src, "(file)", f"a readable {kind}", exc.strerror or str(exc)) from None
    except UnicodeDecodeError as exc:
        raise error(src, "(file)", "UTF-8 text", f"undecodable bytes ({exc.reason})") from None
    except tomllib.TOMLDecodeError as exc:
        raise error(src, "(TOML syntax)", "valid TOML", str(exc)) from None
