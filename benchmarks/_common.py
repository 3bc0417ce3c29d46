"""What the benchmarks share: the environment of a child Python process whose whole CPU they report."""

import atexit
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# imported once, untimed, by child_env's warm-up so that their bytecode is in the cache before any timed child
# (ftstab_mj's own sources are all compiled): what `ftstab run/sweep/montecarlo` import on their way
WARM = ("mujoco", "numpy", "scipy", "pyarrow.parquet", "mcap.records", "foxglove.messages", "lz4.frame", "rerun",
        "ftstab_mj.cli", "ftstab_mj.scenario.run", "ftstab_mj.logs.mcap_sink", "ftstab_mj.metrics.run_metrics",
        "ftstab_mj.studies.sweep.row", "ftstab_mj.studies.sweep.table", "ftstab_mj.studies.montecarlo")

_PYCACHE: list[Path] = []  # one private cache per benchmark process, removed at its exit
_WARMED: set[str] = set()


def child_env(code: Path = ROOT, extra_warm: tuple[str, ...] = (), **overrides: str) -> dict:
    """os.environ for a child ``python`` of the source tree ``code`` (first on PYTHONPATH), with its bytecode
    cached in a private PYTHONPYCACHEPREFIX, as an installed package has it (pip compiles a wheel's modules).

    This machine sets PYTHONDONTWRITEBYTECODE: a child in that environment compiles every module it imports from
    source at each start (~0.1-0.3 s of CPU for ftstab_mj's), a cost of the environment that no install pays.
    The first call for a tree fills the cache, untimed: ftstab_mj's sources compiled, WARM and ``extra_warm``
    imported once (a module outside them is compiled by the first child that imports it: run one untimed).
    ``overrides``: further variables (e.g. OPENBLAS_NUM_THREADS="1")."""
    if not _PYCACHE:
        _PYCACHE.append(Path(tempfile.mkdtemp(prefix="ftstab-bench-pycache-")))
        atexit.register(shutil.rmtree, _PYCACHE[0], True)
    env = dict(os.environ, **overrides)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    env["PYTHONPYCACHEPREFIX"] = str(_PYCACHE[0])
    env["PYTHONPATH"] = os.pathsep.join([str(code), *filter(None, [os.environ.get("PYTHONPATH")])])
    key = f"{Path(code).resolve()}|{','.join(extra_warm)}"
    if key not in _WARMED:
        subprocess.run([sys.executable, "-m", "compileall", "-q", str(Path(code) / "ftstab_mj")], env=env,
                       check=True, stdout=subprocess.DEVNULL)
        imports = "\n".join(f"try:\n    import {m}\nexcept ImportError:\n    pass" for m in (*WARM, *extra_warm))
        subprocess.run([sys.executable, "-c", imports], env=env, cwd=code, stdout=subprocess.DEVNULL,
                       stderr=subprocess.DEVNULL)  # a failure here shows in the first timed child
        _WARMED.add(key)
    return env
