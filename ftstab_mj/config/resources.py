"""Where the package's data lives: the MJCF models and the shipped scenarios.

In a source checkout (and an editable install) they are the repository's top-level ``models/``
and ``scenarios/``. A built wheel carries copies in ``ftstab_mj/_data/`` (setup.py copies them at
build time), so a plain ``pip install .`` works without the source tree. The wheel's copy wins
when present, so an installed package never picks up an unrelated folder beside site-packages.
"""

from __future__ import annotations

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent.parent  # ftstab_mj/ (this file is ftstab_mj/config/resources.py)


def data_dir(name: str) -> Path:
    """The folder ``name`` ("models" or "scenarios"): the wheel's copy, else the source tree's."""
    packaged = _PACKAGE / "_data" / name
    return packaged if packaged.is_dir() else _PACKAGE.parent / name
