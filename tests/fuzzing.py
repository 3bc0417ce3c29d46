"""A seeded fuzzer of the command's input contract (issue 17): mutated scenario files and --set values.

Each case is a shipped scenario with one to three mutations (a value replaced by a hostile one, a
number scaled by a power of ten, a key removed or added, a table replaced, a signal kind or a law
switched), written with the project's TOML writer, plus zero to two random ``--set`` texts. A case
goes through ``ftstab run``'s own ``main`` in process and must keep the contract:

- exit code 0, 1 or 2 (130 never: nothing interrupts), and no exception out of ``main``;
- exit 2: exactly one line on stderr, starting with "error: ", and no output directory;
- no "Traceback" anywhere.

Runs whose scenario the loader accepts are only started when they are short (at most
``max_run_steps`` physics steps, otherwise the case checks the loader only), so a case costs
milliseconds; arm scenarios build their bound tables (~0.5 s) and are drawn less often.

    from fuzzing import fuzz
    report = fuzz(seed=0, cases=300, workdir=tmp_path)   # report.failures == []
"""

from __future__ import annotations

import contextlib
import copy
import io
import random
import shutil
from dataclasses import dataclass, field
from pathlib import Path

from ftstab_mj.cli import main
from ftstab_mj.config.keypath import flatten, parse
from ftstab_mj.scenario import shipped_scenarios
from ftstab_mj.config.tomlfile import dumps, read_toml

DEEP = "[" * 40 + "]" * 40
HOSTILE_VALUES = [
    0, -1, 1, 2, 0.0, -0.0, 1e-320, 5e-324, 1e-7, 1.5, 1e308, -1e308, 1.797e308, float("inf"), float("-inf"),
    float("nan"), 2 ** 31, 2 ** 53 + 1, 2 ** 63 - 1, -(2 ** 63), 2 ** 63, 2 ** 64, 10 ** 20, -(10 ** 30), True, False,
    "", "x", "computed", "a" * 300, "tab\there", "line\nbreak", "caf\u00e9", "\u0000nul", "../../etc/passwd",
    [], [1], [1.0, 2.0], [1.0, 2.0, 3.0], [0.0] * 1000, [[1.0]], [True, "x"], {}, {"kind": "sine"}, {"a": {"b": 1}},
]
SET_PIECES = ["1", "-1", "0", "1e308", "-1e-320", "nan", "inf", "true", '"s"', "'q'", "[", "]", "{", "}", "=",
              ",", ".", "[1, 2]", "{a = 1}", DEEP, "9" * 30, "0x7f", "1_000", '"""', "#", " ", "é", "\\", "[[]]"]
KINDS = ["constant", "step", "sine", "square", "chirp", "random", "worst_case", "triangle"]
LAWS = ["nominal", "robust", "adaptive", "linear", "super_twisting", ""]


@dataclass
class FuzzReport:
    cases: int = 0
    runs: int = 0  # cases whose run was started (the loader accepted them and they were short)
    exits: dict = field(default_factory=dict)  # exit code -> count
    failures: list = field(default_factory=list)  # (case number, what broke, the case)
    scenarios: set = field(default_factory=set)  # the shipped scenarios mutated
    completed_badly: list = field(default_factory=list)  # (case, the case) of exit 1: runs that diverged or failed


def _leaves(raw: dict) -> list[str]:
    return list(flatten(raw))


def _tables(raw: dict) -> list[list]:
    out, stack = [], [([], raw)]
    while stack:
        parts, node = stack.pop()
        if isinstance(node, dict):
            out.append(parts)
            stack.extend((parts + [k], v) for k, v in node.items())
    return out


def _get(raw, parts):
    for p in parts:
        raw = raw[p]
    return raw


def _set(raw, parts, value):
    _get(raw, parts[:-1])[parts[-1]] = value


def mutate(rng: random.Random, raw: dict) -> list[str]:
    """Apply one random mutation to ``raw`` in place; returns a description of it."""
    op = rng.choice(["value", "value", "scale", "delete", "add", "table", "kind", "law"])
    leaves = _leaves(raw)
    if op in ("value", "scale") and leaves:
        path = rng.choice(leaves)
        parts = parse(path)
        if parts is None:
            return [f"skip {path!r}"]
        old = _get(raw, parts)
        if op == "scale" and isinstance(old, (int, float)) and not isinstance(old, bool):
            new = old * 10.0 ** rng.randint(-12, 12) * rng.choice([1, -1])
        else:
            new = copy.deepcopy(rng.choice(HOSTILE_VALUES))
        _set(raw, parts, new)
        return [f"{path} = {new!r}"[:120]]
    tables = _tables(raw)
    parts = rng.choice(tables)
    node = _get(raw, parts) if parts else raw
    if op == "delete" and node:
        key = rng.choice(list(node))
        del node[key]
        return [f"del {'.'.join(map(str, parts + [key]))}"]
    if op == "add":
        key = rng.choice(["extra", "freq_end", "t_step", "modes", "kappa", "phibar", "name", "seed", "grid"])
        node[key] = copy.deepcopy(rng.choice(HOSTILE_VALUES))
        return [f"add {'.'.join(map(str, parts + [key]))} = {node[key]!r}"[:120]]
    if op == "table" and parts:
        new = copy.deepcopy(rng.choice(HOSTILE_VALUES))
        _set(raw, parts, new)
        return [f"{'.'.join(map(str, parts))} = {new!r}"[:120]]
    if op == "kind":
        for p in tables:
            t = _get(raw, p) if p else raw
            if "kind" in t and rng.random() < 0.7:
                t["kind"] = rng.choice(KINDS)
                return [f"{'.'.join(map(str, p))}.kind = {t['kind']!r}"]
    for p in tables:  # law
        t = _get(raw, p) if p else raw
        if "law" in t:
            t["law"] = rng.choice(LAWS)
            return [f"{'.'.join(map(str, p))}.law = {t['law']!r}"]
    return ["no-op"]


def random_set(rng: random.Random, raw: dict) -> str:
    """A --set text: a key path of the scenario (or junk) = a random concatenation of TOML pieces."""
    leaves = _leaves(raw) or ["sim.duration"]
    key = rng.choice(leaves + ["a..b", "x[", "loops.cart.z0[99]", "sim", "plant.mass.x", "seed[0]", ""])
    value = "".join(rng.choice(SET_PIECES) for _ in range(rng.randint(1, 4)))
    return f"{key}={value}" if rng.random() < 0.95 else key


def _steps(path: Path, sets) -> float:
    """Physics steps the scenario would run, or 0 when the loader refuses it."""
    from ftstab_mj.config.errors import FtstabError
    from ftstab_mj.scenario import load_scenario

    try:
        sc = load_scenario(path, sets)
    except FtstabError:
        return 0.0
    return max(sc.sim.duration / sc.sim.physics_step, 1.0)


def fuzz(seed: int, cases: int, workdir: Path, max_run_steps: float = 2000, arm_share: float = 0.1,
         progress=None) -> FuzzReport:
    """Run ``cases`` seeded cases in ``workdir`` (see the module docstring); returns the report."""
    rng = random.Random(seed)
    shipped = [(name, read_toml(path, "scenario")) for name, path, _ in shipped_scenarios()]
    carts = [s for s in shipped if not s[0].startswith("arm")]
    arms = [s for s in shipped if s[0].startswith("arm")]
    report = FuzzReport()
    for case in range(cases):
        # every shipped scenario in turn (arms, whose bound tables cost ~0.5 s, at a lower rate)
        pool = arms if arms and rng.random() < arm_share else carts
        name, base = pool[case % len(pool)]
        report.scenarios.add(name)
        raw = copy.deepcopy(base)
        if isinstance(raw.get("sim"), dict):  # short runs, so that accepted cases can run
            raw["sim"]["duration"] = 0.05
        what = [name]
        for _ in range(rng.randint(1, 3)):
            what += mutate(rng, raw)
        sets = [random_set(rng, raw) for _ in range(rng.choice([0, 0, 1, 2]))]
        what += [f"--set {s}"[:120] for s in sets]
        path = workdir / f"case{case}.toml"
        out = workdir / f"out{case}"
        try:
            path.write_text(dumps(raw), encoding="utf-8")
        except (TypeError, UnicodeEncodeError):  # a value TOML cannot hold: not a case
            continue
        report.cases += 1
        try:
            steps = _steps(path, sets)
        except BaseException as exc:  # noqa: BLE001 - the loader must raise nothing but its own errors
            report.failures.append((case, f"loader: {type(exc).__name__}: {exc}"[:300], what))
            path.unlink()
            continue
        if steps > max_run_steps:  # accepted but long: the loader was the case
            report.exits["accepted, not run"] = report.exits.get("accepted, not run", 0) + 1
            path.unlink()
            continue
        report.runs += steps > 0
        args = ["run", str(path), "--out", str(out)]
        for s in sets:
            args += ["--set", s]
        err, std = io.StringIO(), io.StringIO()
        try:
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(std):
                code = main(args)
        except BaseException as exc:  # noqa: BLE001 - the contract: nothing comes out of main
            report.failures.append((case, f"{type(exc).__name__}: {exc}"[:300], what))
            code = None
        text = err.getvalue()
        report.exits[code] = report.exits.get(code, 0) + 1
        problem = None
        if code not in (0, 1, 2, None):
            problem = f"exit {code}"
        elif "Traceback" in text:
            problem = "a traceback"
        elif code == 2:
            lines = text.strip().splitlines()
            if len(lines) != 1 or not lines[0].startswith("error: "):
                problem = f"{len(lines)} lines for exit 2: {text[:300]!r}"
            elif out.exists():
                problem = "a refused input left an output directory"
        if problem:
            report.failures.append((case, problem, what))
        elif code == 1:
            report.completed_badly.append((case, what))
        shutil.rmtree(out, ignore_errors=True)
        path.unlink(missing_ok=True)
        if progress and (case + 1) % 500 == 0:
            progress(report, case + 1)
    return report
