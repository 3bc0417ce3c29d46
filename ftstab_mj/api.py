"""The Python API: run a scenario, load one, replay a log, from a script or a notebook.

    import ftstab_mj
    sc = ftstab_mj.load_scenario("cart_r2_robust", overrides={"sim.duration": 2})
    res = ftstab_mj.run(sc, out="runs")           # or ftstab_mj.run("cart_r2_robust", ...)
    res.samples["cart"]["V1"], res.metrics["loops"]["cart"]["settle_time"], res.logs
    log = ftstab_mj.replay(res.logs["mcap"])       # the same arrays and metrics, read back

Everything is imported when first called, so ``import ftstab_mj`` stays cheap (no MuJoCo, Rerun).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class Result:
    """What :func:`run` and :func:`replay` return.

    samples: {loop name: {field: NumPy array}} with the fields of records.LOOP_FIELDS (z (n, r),
    others (n,), chain units; time t in s) and any the loop adds; metrics: the metrics dict
    (as ``ftstab run --json`` prints it); status: "completed" | "diverged" | "interrupted" |
    "failed"; message: why a run stopped early; logs: {"mcap": Path} written, and "rrd": Path with
    ``rrd=True`` (empty when ``out`` is None); scenario: the resolved scenario (plain data);
    body_pos (n, nbody, 3) m and body_quat (n, nbody, 4) (w, x, y, z): the bodies' poses (for a
    replay, at the /tf display rate); all three None with ``keep_samples=False``; warning: a replay's
    note on a truncated log, else None; notes: what the testbed made of a user's MJCF model (a
    ctrlrange kept as a saturation, contacts no bound covers, ...), the lines ``ftstab run`` prints as
    ``note:``; () for a shipped plant.
    """

    samples: dict
    metrics: dict
    status: str
    message: str = ""
    logs: dict = field(default_factory=dict)
    scenario: dict = field(default_factory=dict)
    body_pos: object = None
    body_quat: object = None
    warning: str | None = None
    notes: tuple = ()


def _toml(value) -> str:
    """A Python value as a TOML literal: numbers, booleans, strings, lists and dicts (inline tables)."""
    import json
    import math
    import re

    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else ("nan" if value != value else "inf" if value > 0 else "-inf")
    if isinstance(value, str):
        return json.dumps(value)  # a TOML basic string (JSON's escapes are TOML's)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k if re.fullmatch(r'[A-Za-z0-9_-]+', str(k)) else json.dumps(str(k))} = {_toml(v)}"
                               for k, v in value.items()) + "}"
    raise TypeError(f"override value {value!r}: expected a number, boolean, string, list or dict")


def _overrides(overrides) -> list[str]:
    """{"sim.duration": 2} or ["sim.duration=2"] -> the --set texts (dict values as TOML literals:
    numbers, booleans, strings, lists, and dicts as tables: {"loops.cart.controller": {"law": ...}}
    replaces that table, as ``--set 'loops.cart.controller={law = ...}'`` does)."""
    if overrides is None:
        return []
    if isinstance(overrides, dict):
        return [f"{key}={_toml(value)}" for key, value in overrides.items()]
    return [str(o) for o in overrides]


def scenario_from_dict(data: dict, overrides=None, base_dir=None):
    """A validated scenario (ftstab_mj.scenario.Scenario) from plain data shaped as a scenario file
    ({"name": ..., "plant": {"model": ...}, "sim": {...}, "loops": {...}}), checked as a file is.

    overrides: as for :func:`load_scenario`; base_dir: the folder a user model's relative
    ``plant.model`` path is read from (default: the current directory). ``data`` is not modified.
    Raises ScenarioError (one line: key path, expected, found) on bad input."""
    import copy
    from pathlib import Path

    from ftstab_mj.config.errors import ScenarioError
    from ftstab_mj.scenario.loader import apply_override, resolve_relative_paths
    from ftstab_mj.scenario.loader import scenario_from_dict as check

    if not isinstance(data, dict):
        raise ScenarioError("<scenario dict>", "", "a dict shaped as a scenario file", type(data).__name__)
    raw, where = copy.deepcopy(data), {}
    for text in _overrides(overrides):
        where[apply_override(raw, text, "<scenario dict>")] = f"override {text}"
    resolve_relative_paths(raw, Path(base_dir) if base_dir is not None else Path.cwd())
    return check(raw, "<scenario dict>", where)


def load_scenario(name_or_path, overrides=None):
    """A validated scenario (ftstab_mj.scenario.Scenario) from a shipped name ("cart_r2_robust") or
    a .toml path; overrides: {"key.path": value} or ["key.path=value"], validated like the file.
    Raises ScenarioError (one line: file, key path, expected, found) on bad input."""
    from ftstab_mj.scenario import find_scenario
    from ftstab_mj.scenario import load_scenario as load

    return load(find_scenario(str(name_or_path)), _overrides(overrides))


def run(scenario_or_path, out=None, overrides=None, live=False, foxglove=None, realtime=False,
        keep_samples=True, rrd=False) -> Result:
    """Run a scenario (a Scenario, a shipped name or a .toml path) and return its :class:`Result`.

    out: a directory for the MCAP log ``<name>.mcap`` (None: no logs); rrd: also write the Rerun
    recording ``<name>.rrd`` there as the run goes, as ``ftstab run --rrd`` (costs more CPU than the
    physics; ``ftstab view <name>.mcap`` makes the same one afterwards); overrides: as for
    :func:`load_scenario` (not with a Scenario); live: streams the run to Rerun as it happens, as
    ``ftstab run --live`` does: False, True (a native viewer when there is a display, else "serve"),
    "spawn", "serve" (a ``rerun --serve-web`` server on ports 9876/9090, left running), or a
    rerun+http:// URL; foxglove: (host, port) of a Foxglove WebSocket server that publishes the
    MCAP log's messages while the run lasts (needs ``out``; port 0: a free one); realtime: pace the
    run to the wall clock. The samples and logs are the same as without them. keep_samples: False
    keeps none (Result.samples, body_pos, body_quat None): memory does not grow with the run, the
    metrics are the same.
    Raises ScenarioError on bad input, LogError (one line, before anything runs) when ``out`` is a
    file or cannot be made, when the Foxglove address cannot be served on (in use), or a log path there is a directory, a read-only file, or holds what is
    not an ftstab log (another program's file, a symbolic link: ``ftstab run --force`` replaces
    them; the API never does), and CallbackError when the controller raised.
    """
    from ftstab_mj.config.errors import LogError
    from ftstab_mj.logs import RerunSink
    from ftstab_mj.logs.live import LiveView
    from ftstab_mj.logs.run_logs import open_run_logs
    from ftstab_mj.scenario import Scenario, scenario_to_dict
    from ftstab_mj.scenario.run import run_scenario

    if isinstance(scenario_or_path, Scenario):
        if overrides:
            raise ValueError("overrides: expected none with a Scenario object (use load_scenario(path, overrides))")
        sc = scenario_or_path
    else:
        sc = load_scenario(scenario_or_path, overrides)
    if rrd and out is None:
        raise ValueError("rrd: expected out= as well (the directory the recording is written in)")
    if foxglove is not None and out is None:
        raise ValueError("foxglove: expected out= as well (the Foxglove server publishes what the MCAP log gets)")
    run_logs = None if out is None else open_run_logs(out, sc.name, rrd=rrd)  # checked before any viewer starts
    try:
        view = LiveView(live, foxglove, realtime)
    except OSError as exc:  # the Foxglove port in use, or not an address of this host: before any log exists
        raise LogError(f"foxglove {foxglove[0]}:{foxglove[1]}: expected an address to serve on, found "
                       f"{exc.strerror or exc}") from None
    sinks, logs = list(view.sinks()), {}
    try:
        if run_logs is not None:
            logs = {"mcap": run_logs.mcap} | ({"rrd": run_logs.rrd} if rrd else {})
            sinks += run_logs.sinks(view)
        elif view.rerun:
            sinks.append(RerunSink(None, live=view.rerun))
        done = run_scenario(sc, sinks, keep_samples=keep_samples,  # Result.samples
                            batch_size=view.batch_size(sc.sim.period))
    finally:
        view.stop()
    res = done.result
    notes = ()
    if sc.plant.model.endswith(".xml"):  # as `ftstab run` prints them
        from ftstab_mj.plants import make_plant

        notes = tuple(make_plant(sc.plant.model, sc.plant.params).notes)
    return Result(samples=res.loops, metrics=done.metrics, status=res.status, message=res.message, logs=logs,
                  scenario=scenario_to_dict(sc), body_pos=res.body_pos, body_quat=res.body_quat, notes=notes)


def replay(path, keep_samples=True) -> Result:
    """Read a run's MCAP log (also a truncated one) and recompute its metrics from the samples.
    keep_samples: False reads it as it streams (Result.samples and the poses None; memory does not
    grow with the log; the same metrics). Raises LogError when it is not a log, DamagedLog when its
    bytes were altered."""
    from ftstab_mj.logs.reader import read_log, stream_metrics
    from ftstab_mj.metrics.run_metrics import compute_metrics
    from ftstab_mj.simulation.records import INTERRUPTED

    if keep_samples:
        log = read_log(path)
        status = log.recorded["status"] if log.recorded else INTERRUPTED
        metrics = compute_metrics(log.info, log.loops, status)
    else:
        log, metrics = stream_metrics(path)
        status = metrics["status"]
    return Result(samples=log.loops if keep_samples else None, metrics=metrics, status=status,
                  message=(log.recorded or {}).get("message", ""), logs={"mcap": Path(path)},
                  scenario=log.info.scenario, body_pos=log.pose_pos if keep_samples else None,
                  body_quat=log.pose_quat if keep_samples else None, warning=log.warning)
