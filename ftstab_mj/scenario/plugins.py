"""Laws and plants from outside the package: a scenario's ``plugins`` and installed entry points.

Two ways in, both imported before a scenario is validated (so its ``law`` and ``plant.model`` may
name what they register):

* a scenario's top-level ``plugins = ["my_laws.py", "mypkg.laws"]``: a Python file (a path relative
  to the scenario file) or an importable module. The resolved scenario (and so every log) pins each
  one by its content, ``/abs/path/my_laws.py#sha256=<hex>``: a replay, a sweep worker or
  ``replay --verify`` imports the same code, and a missing or changed file is one line, exit 2.
* entry points of installed distributions, groups ``ftstab_mj.laws`` and ``ftstab_mj.plants``
  (``[project.entry-points."ftstab_mj.laws"] my_pd = "mypkg.laws"``): loaded once per process.

A plugin module registers with the public API: ``ftstab_mj.control.register_law`` (a ``Law``
subclass with its ``Param``s) and ``ftstab_mj.plants.register_plant``. :func:`origin` says where a
registered law or plant came from (``ftstab list`` shows it).
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import stat
import sys
from pathlib import Path

from ftstab_mj.config.errors import PluginError, ScenarioError, describe

GROUPS = ("ftstab_mj.laws", "ftstab_mj.plants")
HASH_TAG = "#sha256="
from ftstab_mj.config.limits import MAX_PLUGIN_BYTES  # noqa: E402 - a plugin file is source code

_loaded: dict[str, str] = {}  # imported module name -> where it came from (for origin())
_by_file: dict[tuple[str, str], str] = {}  # (path, sha256) -> module name: each file imported once
_entry_points_done = False


def origin(module: str) -> str:
    """Where the code of ``module`` (a law's or plant's ``__module__``) came from, for ``ftstab list``."""
    if module in _loaded:
        return _loaded[module]
    return "built in" if module.split(".")[0] == "ftstab_mj" else f"module {module}"


def load_plugins(entries, base: Path, error) -> list[str]:
    """Import a scenario's ``plugins`` list; returns the entries pinned by content (the resolved scenario's).

    entries: the raw value of the key; base: the folder relative paths start from (the scenario
    file's); error(key, expected, found) -> the exception to raise (the loader's, naming the file).
    """
    if not isinstance(entries, list) or not all(isinstance(e, str) for e in entries):
        raise error("plugins", "an array of strings (Python files relative to the scenario, or importable "
                    "modules)", describe(entries))
    return [_load_one(entry, base, f"plugins[{i}]", error) for i, entry in enumerate(entries)]


def is_plugin_file(entry: str) -> bool:
    """Whether a ``plugins`` entry names a file (else an importable module)."""
    target = entry.partition(HASH_TAG)[0]
    return target.endswith(".py") or "/" in target or "\\" in target


def _load_one(entry: str, base: Path, key: str, error) -> str:
    target, _, pinned = entry.partition(HASH_TAG)
    if not target:
        raise error(key, "a Python file or a module name", describe(entry))
    if is_plugin_file(target):
        return _load_file(Path(target) if Path(target).is_absolute() else base / target, pinned, key, error)
    return _load_module(target, pinned, key, error)


def _digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _read_source(path: Path, key: str, error) -> bytes:
    """The bytes of a plugin file: a regular file (never a FIFO or a device) of bounded size."""
    try:
        st = path.stat()
    except OSError as exc:
        raise error(key, "an existing Python file (relative to the scenario file)",
                    f"{path.name}: {exc.strerror or 'not found'}") from None
    if not stat.S_ISREG(st.st_mode):
        raise error(key, "a regular Python file", f"{path.name}: not a regular file")
    if st.st_size > MAX_PLUGIN_BYTES:
        raise error(key, f"a Python file of at most {MAX_PLUGIN_BYTES} bytes", f"{path.name}: {st.st_size} bytes")
    return path.read_bytes()


def _check_pin(pinned: str, digest: str, what: str, key: str, error) -> None:
    if pinned and pinned != digest:
        raise error(key, f"{what} with the content it was recorded with (sha256 {pinned[:12]}...)",
                    f"a changed file (sha256 {digest[:12]}...)")


def _load_file(path: Path, pinned: str, key: str, error) -> str:
    path = path.resolve()
    data = _read_source(path, key, error)
    digest = _digest(data)
    _check_pin(pinned, digest, path.name, key, error)
    name = _by_file.get((str(path), digest))
    if name is None:
        name = f"ftstab_mj_plugin_{path.stem}_{digest[:12]}"
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        try:
            spec.loader.exec_module(module)
        except Exception as exc:  # the plugin's own error: one line naming it, never a traceback
            del sys.modules[name]
            raise error(key, f"a plugin that imports ({path.name})", _failure(exc, path)) from None
        _by_file[(str(path), digest)] = name
        _loaded[name] = f"plugin {path}"
    return f"{path}{HASH_TAG}{digest}"


def _load_module(name: str, pinned: str, key: str, error) -> str:
    try:
        module = importlib.import_module(name)
    except ModuleNotFoundError as exc:
        if exc.name and name.startswith(exc.name):
            raise error(key, "an importable module (or a file ending in .py)", f"no module named {name!r}") from None
        raise error(key, f"a plugin that imports ({name})", _failure(exc, None)) from None
    except Exception as exc:
        raise error(key, f"a plugin that imports ({name})", _failure(exc, None)) from None
    _loaded.setdefault(name, f"module {name}")
    source = getattr(module, "__file__", None)
    if not source:
        return name
    digest = _digest(Path(source).read_bytes())
    _check_pin(pinned, digest, f"module {name}", key, error)
    return f"{name}{HASH_TAG}{digest}"


def _failure(exc: BaseException, path: Path | None) -> str:
    """One line for an exception raised while importing a plugin: its type, message and line."""
    tb, line = exc.__traceback__, None
    while tb is not None:
        if path is None or Path(tb.tb_frame.f_code.co_filename).resolve() == path:
            line = tb.tb_lineno
        tb = tb.tb_next
    text = str(exc).splitlines()[0] if str(exc) else ""
    return f"{type(exc).__name__}: {text}" + (f" (line {line})" if line and path is not None else "")


def ensure(sc) -> None:
    """Import the plugins and entry points a validated scenario ``sc`` was read with, where they are not
    yet (a process that received the scenario itself, e.g. a Dask worker, never read its file).
    Its entries are pinned (absolute path or module, and sha256): a changed file is refused."""
    load_entry_points()
    if sc.plugins:
        load_plugins(list(sc.plugins), Path.cwd(),
                     lambda key, expected, found: ScenarioError(f"scenario {sc.name}", key, expected, found))


def load_entry_points() -> None:
    """Import every entry point of the groups ``ftstab_mj.laws`` and ``ftstab_mj.plants`` (once).

    An entry point names a module (which registers its laws or plants when imported) or a ``Law``
    subclass (registered here if it is not yet). A broken one is a PluginError naming it.
    """
    global _entry_points_done
    if _entry_points_done:
        return
    _entry_points_done = True
    from importlib.metadata import entry_points

    from ftstab_mj.control.law import LAWS, Law, register_law

    for group in GROUPS:
        for ep in entry_points(group=group):
            dist = ep.dist.name if ep.dist is not None else "?"
            where = f"entry point {ep.name!r} of {dist} (group {group})"
            try:
                obj = ep.load()
            except Exception as exc:
                _entry_points_done = False  # the next attempt says it again
                raise PluginError(f"{where}: expected {ep.value!r} to import, found {_failure(exc, None)}") from None
            module = getattr(obj, "__name__", ep.module) if not isinstance(obj, type) else obj.__module__
            _loaded.setdefault(module, f"distribution {dist}")
            if isinstance(obj, type) and issubclass(obj, Law) and LAWS.get(obj.name) is not obj:
                register_law(obj)
