"""What the docs site shows of the package's own declarations, printed as Markdown (run by the hook in
a subprocess, so that the checkout's package is the one read, whatever is installed).

    python docs/hooks/generate.py schema     # the scenario file's tables: key, type, default, allowed, meaning
    python docs/hooks/generate.py help       # {verb: `ftstab VERB --help`} as JSON

The schema tables come from the scenario's dataclasses: a field's type and default from the class, its
meaning from the field's ``doc``, its allowed values from the loader's own check (asked about a value
that no check accepts, it says what it accepts). The signal and reference tables add each kind's keys.
"""

import argparse
import dataclasses
import json
import math
import os
import re
import sys
import typing


def _type_name(tp) -> str:
    """A field type as a scenario writer reads it (TOML words, not Python's)."""
    args = typing.get_args(tp)
    if typing.get_origin(tp) is tuple and dataclasses.is_dataclass(args[0]):
        return "tables"  # [loops.NAME]: one table a name
    if typing.get_origin(tp) is tuple:
        return "array of " + _type_name(args[0]) + "s"
    if args:  # a union: None is a default, a law object is the Python API's, not a file's
        return " or ".join(_type_name(a) for a in args if a is not type(None) and a.__name__ != "Law")
    if dataclasses.is_dataclass(tp):
        return "table"
    return {float: "number", int: "integer", str: "string", bool: "boolean", dict: "table"}.get(tp, tp.__name__)


def _default(f) -> str:
    if f.default is not dataclasses.MISSING:
        value = f.default
    elif f.default_factory is not dataclasses.MISSING:
        value = f.default_factory()
    else:
        return "**required**"
    if value is None:
        return "none"
    if dataclasses.is_dataclass(value):
        return "see below" if not hasattr(value, "kind") else f'kind = "{value.kind}"'
    if isinstance(value, tuple):
        return "[" + ", ".join(f"{v:g}" if isinstance(v, float) else repr(v) for v in value) + "]"
    if isinstance(value, str):
        return f'"{value}"'
    return f"{value:g}" if isinstance(value, float) else str(value)


def _allowed(check, tp) -> str:
    """What ``check`` accepts, in its own words: asked about a value that none accepts."""
    if check is None:
        return ""
    probe = "" if tp is str else -math.inf
    try:
        said = check(probe)
    except (TypeError, ValueError):
        said = check((probe,))
    return said or ""


def _cell(text: str) -> str:
    text = re.sub(r"\s*\(ftstab_mj/[^)]*\)", "", str(text))  # a module's path: for the next engineer, not here
    return " ".join(text.split()).replace("|", "\\|")


def _table(cls, checks=None, skip=(), docs=None) -> str:
    hints = typing.get_type_hints(cls)
    rows = ["| key | type | default | allowed | meaning |", "|---|---|---|---|---|"]
    for f in dataclasses.fields(cls):
        if f.name in skip or not f.init:
            continue
        check = (checks or {}).get(f.name, f.metadata.get("check"))
        doc = f.metadata.get("doc") or (docs or {}).get(f.name, "")
        rows.append(f"| `{f.name}` | {_type_name(hints[f.name])} | {_cell(_default(f))} | "
                    f"{_cell(_allowed(check, hints[f.name]))} | {_cell(doc)} |")
    return "\n".join(rows)


def _docstring_fields(cls) -> dict:
    """{name: text} from a docstring that describes its fields as "name, name: text" after its first
    line, one entry a line (Signal) or separated by "; " (MetricSettings)."""
    names = {f.name for f in dataclasses.fields(cls)}
    out, last = {}, []
    for sep, part in zip(["; "] + re.findall(r";\s+|\n", cls.__doc__), re.split(r";\s+|\n", cls.__doc__)):
        head, _, rest = part.partition(": ")
        keys = [k.strip().split()[-1] for k in head.split(",") if k.strip()]
        if keys and set(keys) <= names and rest:
            last = keys
            for key in keys:
                out[key] = rest
        else:  # the text of the entry above goes on
            for key in last:
                out[key] += sep + part
    return {key: " ".join(text.split()).rstrip(".") for key, text in out.items()}


def _used_by(by_kind) -> dict:
    """{key: "kinds: a, b"}: which kinds of a signal or reference read a key."""
    return {key: "kinds: " + ", ".join(k for k, keys in by_kind.items() if key in keys)
            for key in {key for keys in by_kind.values() for key in keys}}


def schema() -> str:
    from ftstab_mj.plants import disturbances, reference
    from ftstab_mj.scenario import schema as s
    from ftstab_mj.simulation.records import MetricSettings

    out = []

    def section(title, cls, intro, **kw):
        out.extend([f"### {title}", "", " ".join(intro.split()), "", _table(cls, **kw), ""])

    section("Top level", s.Scenario, "The file's top-level keys; `[plant]`, `[sim]`, `[metrics]` and "
            "`[loops.<name>]` are the tables below.")
    section("[plant]", s.PlantSpec, "`model`, then the model's own physical parameters as keys of the "
            "same table (`mass = 1.0`; each plant's keys, units and defaults: the listing at the end of "
            "this page).", skip=("params",))
    section("[sim]", s.SimSpec, s.SimSpec.__doc__)
    section("[metrics]", MetricSettings, "How the metrics read the run (every key optional).",
            checks=s.EXTERNAL_CHECKS[MetricSettings], docs=_docstring_fields(MetricSettings))
    section("[loops.NAME]", s.LoopSpec, "One table per loop of the plant (the cart: `cart`; the arm: "
            "`joint0`, `joint1`; a model of yours: the loops its `[plant.loops]` declares).", skip=("name",))
    section("[loops.NAME.sensor]", s.SensorSpec, s.SensorSpec.__doc__, skip=s.SIGNAL_DERIVED)
    section("[loops.NAME.observer]", s.ObserverSpec, s.ObserverSpec.__doc__)
    section("[loops.NAME.actuator]", s.ActuatorSpec, s.ActuatorSpec.__doc__)

    def kinds(title, cls, by_kind, intro):
        rows = ["| kind | its keys |", "|---|---|"]
        rows += [f"| `{k}` | {', '.join(f'`{key}`' for key in keys if key not in ('times', 'values'))} |"
                 for k, keys in by_kind.items()]
        docs = {key: "; ".join(filter(None, (text, _docstring_fields(cls).get(key))))
                for key, text in _used_by(by_kind).items()}
        defaults = _table(cls, skip=("kind", *s.SIGNAL_DERIVED, "times", "values"), docs=docs)
        out.extend([f"### {title}", "", " ".join(intro.split()), "", "\n".join(rows), "",
                    "Every key, with its type and default:", "", defaults, ""])

    kinds("[loops.NAME.disturbance] and [loops.NAME.gain]", disturbances.Signal, disturbances.KEYS_BY_KIND,
          "A signal, offset + amplitude * shape(t): phi(t) (the disturbance) or gamma(t) (the gain, default "
          "a constant 1; never `worst_case`). A kind takes only its own keys; the values are in the "
          "units of phi or gamma (chain units; the arm: a torque in N m and a gain factor).")
    kinds("[loops.NAME.reference]", reference.Reference, reference.KEYS_BY_KIND,
          "ref(t) to track instead of the set point `ref`: z_i = q^(i-1) - ref^(i-1)(t). Times in s, "
          "positions in m or rad, `freq` in Hz, `phase` in rad; a `file` is a CSV of lines `t, value` and "
          "`smooth` its number of continuous derivatives (the loop's r <= smooth + 1).")
    return "\n".join(out)


def helps() -> str:
    from ftstab_mj.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return json.dumps({verb: p.format_help() for verb, p in sub.choices.items()})


if __name__ == "__main__":
    os.environ["COLUMNS"] = "100"  # the same wrapping on every terminal
    print({"schema": schema, "help": helps}[sys.argv[1]]())
