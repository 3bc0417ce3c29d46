"""The certificate of a parameter set, computed once: in this process and on disk.

A run's metrics need the certificate of its controller (T(z0), Theorem 3); the branch and bound
costs from 0.01 s to minutes, and the same parameter sets come back in every run and sweep row.
:func:`cached_certify` keeps each result in memory and in a JSON file named by a hash of the
parameters and of the source of the code that computes it (so a change of that code is a new key,
never a stale answer). The directory is ``$FTSTAB_CACHE_DIR``, else ``$XDG_CACHE_HOME/ftstab_mj``,
else ``~/.cache/ftstab_mj``; when it cannot be written the cache is in-process only. A file that
cannot be read back exactly (damaged, another version, another key) is ignored and recomputed.
Only deterministic computations are cached: no time budget (the B&B stops at its gap or at the
work limit ``max_boxes``, part of the key).
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import tempfile
from pathlib import Path

from ftstab_mj.control import certificate as _cert
from ftstab_mj.control import design as _design  # its Nelder-Mead polishes the witness, which decides where the B&B stops
from ftstab_mj.control import hong as _hong
from ftstab_mj.control import hong_terms as _terms
from ftstab_mj.control import interval as _interval

_MEMORY: dict[str, _cert.Certificate] = {}
# the same certificates by their arguments (floats as hex: -0.0 is not 0.0, as in the key): a run's metrics
# ask for the certificate of each loop ~6 times, and the key's JSON and SHA-256 cost ~12 us each time (this: ~4)
_BY_ARGS: dict[tuple, _cert.Certificate] = {}
_CODE: str | None = None


def code_version() -> str:
    """A hash of the source files the certificate depends on."""
    global _CODE
    if _CODE is None:
        h = hashlib.sha256()
        for mod in (_cert, _design, _hong, _terms, _interval):
            h.update(Path(mod.__file__).read_bytes())
        _CODE = h.hexdigest()[:16]
    return _CODE


def cache_dir() -> Path:
    env = os.environ.get("FTSTAB_CACHE_DIR")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "ftstab_mj"


def cache_key(r: int, k: float, gains: tuple, form: str, max_boxes: int = _cert.DEFAULT_MAX_BOXES) -> str:
    ident = json.dumps({"r": int(r), "k": float(k).hex(), "gains": [float(g).hex() for g in gains], "form": form,
                        "samples": _cert.DEFAULT_SAMPLES, "seed": _cert.DEFAULT_SEED, "rtol": _cert.DEFAULT_RTOL,
                        "max_boxes": int(max_boxes), "code": code_version()}, sort_keys=True)
    return hashlib.sha256(ident.encode()).hexdigest()[:32]


def cached_certify(r: int, k: float, gains: tuple, form: str = "full", max_boxes: int = _cert.DEFAULT_MAX_BOXES,
                   progress=None) -> _cert.Certificate:
    """certify(HongController(r, k, gains, form), max_boxes=max_boxes) with the other defaults, from
    the cache when it is there. progress(text): called now and then while it is computed (not on a hit)."""
    gains = tuple(float(g) for g in gains)
    args = (int(r), float(k).hex(), tuple(g.hex() for g in gains), form, int(max_boxes))
    cert = _BY_ARGS.get(args)
    if cert is not None:
        return cert
    key = cache_key(r, k, gains, form, max_boxes)
    if key in _MEMORY:
        _BY_ARGS[args] = _MEMORY[key]
        return _MEMORY[key]
    path = cache_dir() / f"certificate-{key}.json"
    cert = _read(path, key)
    if cert is None:
        with _computing(path):  # another process computing the same key: wait for its file
            cert = _read(path, key)
            if cert is None:
                cert = _cert.certify(_hong.HongController(r, k, gains, form=form), max_boxes=int(max_boxes),
                                     progress=progress)
                _write(path, key, cert)
    _MEMORY[key] = _BY_ARGS[args] = cert
    return cert


@contextlib.contextmanager
def _computing(path: Path):
    """An exclusive lock on ``path``'s key (a .lock file beside it, flock): processes that miss the
    cache at once (a sweep's workers, a test suite's) compute a certificate once, the others read it.
    No lock where the directory cannot be written (each process computes its own)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(path.with_suffix(".lock"), os.O_RDWR | os.O_CREAT, 0o644)
    except OSError:
        yield
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # releases the lock


def _read(path: Path, key: str):
    try:
        data = json.loads(path.read_text())
        if data.get("key") != key:
            return None
        d = dict(data["certificate"])
        d.pop("seconds", None)
        d["witness"] = None if d["witness"] is None else tuple(d["witness"])
        return _cert.Certificate(**d, seconds=float(data["seconds"]))
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _write(path: Path, key: str, cert: _cert.Certificate) -> None:
    """Atomically (a temporary file renamed into place); silently skipped when not writable."""
    text = json.dumps({"key": key, "certificate": cert.to_dict(), "seconds": cert.seconds})
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".certificate-", suffix=".tmp")
    except OSError:
        return
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    except OSError:
        Path(tmp).unlink(missing_ok=True)


def clear_memory() -> None:
    """Forget the in-process copies (tests)."""
    _MEMORY.clear()
    _BY_ARGS.clear()
