"""MkDocs hook: the pages' generated parts, from the package's own declarations (one source of truth).

- `<!-- ftstab list -->`: what `ftstab list` prints today (the laws with their keys' doc, unit and
  default, and the plants), the scenario loader's and `ftstab list`'s own source;
- `<!-- ftstab schema -->`: the scenario file's tables, key by key (docs/hooks/generate.py schema);
- `<!-- ftstab help VERB -->`: `ftstab VERB --help` (every option of a verb, on its page).

Each runs the checkout's package in a subprocess (whatever ftstab_mj is installed), once per build.
"""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
_cache = {}


def _run(*argv) -> str:
    if argv not in _cache:
        env = dict(os.environ, COLUMNS="100")
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH", "")) if p)
        proc = subprocess.run([sys.executable, *argv], capture_output=True, text=True, cwd=ROOT, env=env,
                              timeout=120, check=True)
        _cache[argv] = proc.stdout
    return _cache[argv]


def _ftstab_list() -> str:
    text = _run("-m", "ftstab_mj", "list")
    # the first part lists the scenarios of this checkout, with its path: keep laws and plants
    text = text[text.index("laws ("):] if "laws (" in text else text
    return "```text\n" + text.rstrip() + "\n```"


def _help(verb: str) -> str:
    helps = json.loads(_run(str(ROOT / "docs" / "hooks" / "generate.py"), "help"))
    return "```text\n" + helps[verb].rstrip() + "\n```"


def on_page_markdown(markdown, page, config, files):
    markdown = markdown.replace("<!-- ftstab list -->", _ftstab_list()) if "<!-- ftstab list -->" in markdown else markdown
    if "<!-- ftstab schema -->" in markdown:
        markdown = markdown.replace("<!-- ftstab schema -->", _run(str(ROOT / "docs" / "hooks" / "generate.py"), "schema"))
    return re.sub(r"<!-- ftstab help (\w+) -->", lambda m: _help(m.group(1)), markdown)
