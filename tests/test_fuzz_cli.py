"""Every option of every verb under hostile values (issue 44, point 5), found from the argparse parsers
(cli/<verb>.py add_parser), so an option added later is covered without editing this file:

- an option that converts its value (``type=``: numbers, ports, lists of numbers) gets -1, 0, 1e308, nan, inf
  and -1e-3 (a value, never an option: "expected one argument" fails the case);
- an option that names a file or folder (no ``type=``, no ``choices``) gets a FIFO, a directory, a symbolic
  link loop, /dev/zero, a path in a read-only folder and an existing file that is not what it expects; a
  log read from a FIFO is fed a valid log by a writer (it must stream), any other FIFO gets no writer.

Each case is the verb's cheap base command (a 10 ms run, a 200-sample certificate, ...) with one value
replaced, run through ``main`` in one worker process (imports paid once) under a per-case alarm, the worker
itself in a process group of its own with a deadline, killed whatever happens: a hang fails the case, never
the suite. Contract: exit 0, 1 or 2; exit 2 is one line on stderr starting with "error: "; no traceback.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from conftest import ROOT

NUMBERS = ("-1", "0", "1e308", "nan", "inf", "-1e-3")  # -1e-3: argparse took it for an option (certify --k)
PATHS = ("fifo", "directory", "symlink_loop", "/dev/zero", "read_only_folder", "existing_file")
NOT_PATHS = {"--set": "KEY=VALUE texts (tests/fuzzing.py)", "--loop": "a loop's name",
             "--scheduler": "a Dask scheduler's address"}
CASE_SECONDS = 30  # one case's alarm: the slowest base command takes ~2 s on a loaded machine
DEADLINE = 300  # s for the whole worker


def write_inputs(d: Path) -> None:
    """The tiny sweep and comparison files of :func:`base_commands` in ``d``."""
    cart = ROOT / "scenarios" / "cart_r2_robust.toml"
    (d / "fz.sweep.toml").write_text(f'name = "fz"\ndescription = "fuzz base"\nscenario = "{cart}"\nsamples = 1\n[set]\n"sim.duration" = 0.01\n'
                                     '[grid]\n"loops.cart.controller.phibar" = [1.0, 2.0]\n')
    (d / "fz.compare.toml").write_text(f'name = "fzc"\ndescription = "fuzz base"\nscenario = "{cart}"\nsteps_per_period = 1\n[set]\n'
                                       '"sim.duration" = 0.01\n[grid]\n"sim.period" = [1e-3]\n[[laws]]\nlabel = "robust"\n'
                                       'controller = { law = "robust", k = -0.2, gains = [1.0, 2.0], phibar = 1.0, '
                                       'gamma_m = 0.5 }\n')


def base_commands(d: Path, log: Path) -> dict[str, list[str]]:
    """The cheapest valid command of each verb (its files in ``d``: :func:`write_inputs`; ``log`` a small run log)."""
    return {
        "certify": ["certify", "--r", "2", "--k", "-0.2", "--gains", "1,2", "--samples", "200", "--budget", "1"],
        "design": ["design", "--r", "2", "--k", "-0.2", "--budget", "1", "--max-boxes", "50"],
        "replay": ["replay", str(log)],
        "check": ["check", str(log), "--pin", "OUT/pin.toml"],
        "report": ["report", str(log), "--out", "OUT/fig.png"],
        "view": ["view", str(log), "--open", "none", "--rrd", "OUT/v.rrd"],
        "run": ["run", "cart_r2_robust", "--out", "OUT/runs", "--set", "sim.duration=0.01"],
        "sweep": ["sweep", str(d / "fz.sweep.toml"), "--out", "OUT/sw"],
        "montecarlo": ["montecarlo", "cart_r2_robust", "--states", "4", "--box", "0.1,0.1", "--out", "OUT/mc"],
        "compare": ["compare", str(d / "fz.compare.toml"), "--out", "OUT/cmp"],
    }


def options():
    """(verb, option string or None for a positional, its position, kind "number" | "path") of every
    option of every verb that takes a value."""
    from ftstab_mj.cli import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    out = []
    for verb, parser in sub.choices.items():
        positional = 0
        for a in parser._actions:
            if a.nargs == 0 or a.choices is not None:
                continue
            opt = a.option_strings[0] if a.option_strings else None
            if opt in NOT_PATHS:
                continue
            out.append((verb, opt, None if opt else positional, "number" if a.type is not None else "path"))
            positional += opt is None
    return out


def with_value(base: list[str], opt, position, value: str) -> list[str]:
    argv = list(base)
    if opt is None:
        argv[1 + position] = value
    elif opt in argv:
        argv[argv.index(opt) + 1] = value
    else:
        argv += [opt, value]
    return argv


def hostile_path(kind: str, case: Path, valid: Path | None) -> str:
    """A path of ``kind`` made in the case's folder ``case``."""
    if kind == "/dev/zero":
        return kind
    p = case / "target"
    if kind == "fifo":
        os.mkfifo(p)
    elif kind == "directory":
        p.mkdir()
    elif kind == "symlink_loop":
        os.symlink(case / "other", p)
        os.symlink(p, case / "other")
    elif kind == "read_only_folder":
        ro = case / "ro"
        ro.mkdir()
        p = ro / (valid.name if valid is not None else "target")
        if valid is not None:
            p.write_bytes(valid.read_bytes())
        ro.chmod(0o555)
    elif kind == "existing_file":
        p.write_text("not what this option expects\n")
    return str(p)


class CaseTimeout(BaseException):
    pass


def _alarm(signum, frame):
    raise CaseTimeout()


def feed(fifo: str, data: bytes) -> threading.Thread:
    """A writer of ``data`` into ``fifo`` (a log streamed from a pipe), released by :func:`release`."""
    def write():
        try:
            with open(fifo, "wb") as f:
                f.write(data)
        except OSError:  # the reader left early (a refusal after the first bytes)
            pass

    t = threading.Thread(target=write, daemon=True)
    t.start()
    return t


def release(fifo: str, writer: threading.Thread) -> None:
    """Let a writer still waiting for a reader go (the command refused the FIFO without opening it)."""
    if writer.is_alive():
        try:
            fd = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)
            os.close(fd)
        except OSError:
            pass
        writer.join(5)


def one_case(argv: list[str], out_dir: Path) -> dict:
    """Run ``main(argv)`` with stdout and stderr captured at the file descriptors (MuJoCo's C prints too)."""
    import tempfile

    from ftstab_mj.cli import main

    out_dir.mkdir(parents=True, exist_ok=True)
    argv = [a.replace("OUT", str(out_dir)) for a in argv]
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    with tempfile.TemporaryFile() as fo, tempfile.TemporaryFile() as fe:
        os.dup2(fo.fileno(), 1)
        os.dup2(fe.fileno(), 2)
        signal.alarm(CASE_SECONDS)
        try:
            code = main(argv)
        except CaseTimeout:
            code = "hang"
        except SystemExit as exc:  # argparse's own refusals
            code = exc.code
        except BaseException:  # noqa: BLE001 - what escaped main is the failure reported
            import traceback

            code = "raised"
            traceback.print_exc()
        finally:
            signal.alarm(0)
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)
        fo.seek(0)
        fe.seek(0)
        return {"argv": argv, "code": code, "out": fo.read().decode(errors="replace")[-2000:],
                "err": fe.read().decode(errors="replace")[-2000:]}


def worker(workdir: str, results: str) -> None:
    """Every case, one after the other, in this process; their outcomes as JSON lines into ``results``."""
    from ftstab_mj.cli import main

    d = Path(workdir)
    signal.signal(signal.SIGALRM, _alarm)
    with open(os.devnull, "w") as null:
        os.dup2(null.fileno(), 1)
        assert main(["run", "cart_r2_robust", "--out", str(d / "log"), "--set", "sim.duration=0.05"]) == 0
    log = d / "log" / "cart_r2_robust.mcap"
    write_inputs(d)
    bases = base_commands(d, log)
    with open(results, "w") as f:
        for verb, base in bases.items():  # each base command is valid: a refusal below is the value's
            outcome = one_case(base, d / f"base_{verb}" / "out")
            outcome.update(verb=verb, option=None, kind="base", value=None)
            f.write(json.dumps(outcome) + "\n")
        for n, (verb, opt, position, kind) in enumerate(options()):
            base = bases[verb]
            valid = None
            if opt is None:
                valid = Path(base[1 + position]) if Path(base[1 + position]).is_file() else None
            for hostile in NUMBERS if kind == "number" else PATHS:
                value = hostile
                case = d / f"case{n}_{value.strip('/').replace('/', '_')}"
                case.mkdir()
                writer = None
                if kind == "path":
                    path = hostile_path(value, case, valid)
                    if value == "fifo" and valid is not None and valid.suffix == ".mcap":
                        writer = feed(path, valid.read_bytes())  # a log from a pipe streams
                    value = path
                outcome = one_case(with_value(base, opt, position, value), case / "out")
                if writer is not None:
                    release(path, writer)
                outcome.update(verb=verb, option=opt or f"<positional {position}>", kind=kind, value=hostile)
                f.write(json.dumps(outcome) + "\n")
                f.flush()


def problems(outcome: dict) -> str | None:
    code, err = outcome["code"], outcome["err"]
    if code not in (0, 1, 2):
        return f"exit {code}"
    if "Traceback" in err or "Traceback" in outcome["out"]:
        return "a traceback"
    lines = [line for line in err.splitlines() if line.strip()]
    if code == 2 and (len(lines) != 1 or not lines[0].startswith("error: ")):
        return f"exit 2 with {len(lines)} stderr lines, not one 'error: ' line"
    if "expected one argument" in err:
        return "a negative number taken for an option"
    return None


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory):
    d = tmp_path_factory.mktemp("fuzz_cli")
    results = d / "results.jsonl"
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + str(ROOT / "tests") + os.pathsep
               + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.Popen([sys.executable, "-c", f"import test_fuzz_cli as t; t.worker({str(d)!r}, {str(results)!r})"],
                            cwd=d, env=env, start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        _, err = proc.communicate(timeout=DEADLINE)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        _, err = proc.communicate()
        err = f"the worker did not end within {DEADLINE} s\n{err}"
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    assert proc.returncode == 0, err[-3000:]
    return [json.loads(line) for line in results.read_text().splitlines()]


def test_every_base_command_runs(outcomes):
    base = {o["verb"]: (o["code"], o["err"][-500:]) for o in outcomes if o["kind"] == "base"}
    assert base.keys() == base_commands(Path("/nonexistent"), Path("x")).keys()
    assert {verb: code for verb, (code, _) in base.items()} == dict.fromkeys(base, 0), base


def test_every_option_is_fuzzed(outcomes):
    outcomes = [o for o in outcomes if o["kind"] != "base"]
    found = {(o["verb"], o["option"], o["kind"]) for o in outcomes}
    expected = {(verb, opt or f"<positional {pos}>", kind) for verb, opt, pos, kind in options()}
    assert found == expected
    assert len(outcomes) == sum(len(NUMBERS if k == "number" else PATHS) for *_, k in options())
    assert {o["kind"] for o in outcomes} == {"number", "path"}
    assert len(found) > 40  # 44 options when this was written
    assert {o["verb"] for o in outcomes} == set(base_commands(Path("/nonexistent"), Path("x")))  # every verb


def test_every_hostile_value_gives_one_line_or_a_result(outcomes):
    bad = [f"{' '.join(o['argv'][:6])}: {p}\n{o['err'][-600:]}" for o in outcomes if (p := problems(o))]
    assert not bad, f"{len(bad)} of {len(outcomes)} cases:\n" + "\n".join(bad[:15])


def test_a_log_from_a_fifo_streams_and_dev_zero_is_refused(outcomes):
    logs = [o for o in outcomes if o["verb"] in ("replay", "check") and o["option"] == "<positional 0>"]
    fifo = [o for o in logs if o["value"] == "fifo" and o["code"] == 0]
    assert {o["verb"] for o in fifo} == {"replay", "check"}  # a valid log written into the FIFO is read
    zero = [o for o in logs if o["value"] == "/dev/zero"]
    assert zero and all(o["code"] == 2 for o in zero)
