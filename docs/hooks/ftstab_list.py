"""MkDocs hook: a page's `<!-- ftstab list -->` line becomes what `ftstab list` prints today.

The scenario reference's laws, their keys (with doc, unit and default) and the plants then come from
the package's own declarations, the one source `ftstab list` and the scenario loader read.
"""

import os
import subprocess
import sys
from pathlib import Path

MARKER = "<!-- ftstab list -->"
ROOT = Path(__file__).resolve().parents[2]
_cache = {}


def _ftstab_list() -> str:
    if "out" not in _cache:
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH", "")) if p)
        proc = subprocess.run([sys.executable, "-m", "ftstab_mj", "list"], capture_output=True, text=True,
                              cwd=ROOT, env=env, timeout=120, check=True)
        text = proc.stdout
        # the first part lists the scenarios of this checkout, with its path: keep laws and plants
        text = text[text.index("laws ("):] if "laws (" in text else text
        _cache["out"] = text.rstrip()
    return _cache["out"]


def on_page_markdown(markdown, page, config, files):
    if MARKER not in markdown:
        return markdown
    return markdown.replace(MARKER, "```text\n" + _ftstab_list() + "\n```")
