"""Limits and path kinds (issue 44: H3, R1, R3): every input file is a regular file of bounded size, a log from a
pipe streams while /dev/zero is refused at its first bytes, and the limits table is one table. Through the real
CLI, each command with a deadline (a FIFO that blocked would fail the test, not hang the suite)."""

import os
import shutil
import subprocess

import pytest

from conftest import ROOT, run_cli
from test_plants_user import ASSETS, PENDULUM, _scenario

DEADLINE = 60


def one_line_error(proc, *words):
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and lines[0].startswith("error: "), proc.stderr
    assert "Traceback" not in proc.stderr and all(w in lines[0] for w in words), lines[0]
    return lines[0]


def model_kinds(tmp_path):
    """{kind: model path} of model files that are not regular files of bounded size."""
    d = tmp_path / "models"
    d.mkdir()
    os.mkfifo(d / "fifo.xml")
    (d / "dir.xml").mkdir()
    os.symlink(d / "loop2.xml", d / "loop1.xml")
    os.symlink(d / "loop1.xml", d / "loop2.xml")
    os.symlink("/dev/zero", d / "zero.xml")
    with open(d / "big.xml", "wb") as f:  # sparse: 17 MiB that take no disk
        f.truncate(17 << 20)
    text = (ASSETS / "inverted_pendulum.xml").read_text()
    for name, target in (("inc_fifo.xml", "fifo.xml"), ("inc_zero.xml", "zero.xml")):
        (d / name).write_text(text.replace("<worldbody>", f'<include file="{target}"/><worldbody>', 1))
    return {"FIFO (named pipe)": d / "fifo.xml", "directory": d / "dir.xml", "symlink loop": d / "loop1.xml",
            "character device": d / "zero.xml", "16777216 bytes": d / "big.xml",
            "include that is a regular file, found": d / "inc_fifo.xml",
            "include that is a regular file": d / "inc_zero.xml"}


@pytest.mark.parametrize("kind", ["FIFO (named pipe)", "directory", "symlink loop", "character device",
                                  "16777216 bytes", "include that is a regular file, found",
                                  "include that is a regular file"])
def test_a_model_or_include_that_is_not_a_bounded_regular_file_is_one_line(tmp_path, kind):
    """H3/R3: a model or an <include> that is a FIFO blocked for ever in MuJoCo's reader; /dev/zero never ended;
    a symlink loop was a traceback; a 200 MB model cost a minute and 1.9 GB before any refusal."""
    model = model_kinds(tmp_path)[kind]
    path = _scenario(tmp_path, str(model), PENDULUM)
    proc = run_cli("run", path, "--out", tmp_path / "out", timeout=DEADLINE)
    one_line_error(proc, str(path), "plant.model:", kind.split(",")[0])
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("make, found", [
    (lambda p: os.mkfifo(p), "a FIFO (named pipe)"), (lambda p: p.mkdir(), "a directory"),
    (lambda p: (os.symlink(p.with_name("b.toml"), p), os.symlink(p, p.with_name("b.toml"))), "a symlink loop"),
    (lambda p: os.symlink("/dev/zero", p), "a character device")])
@pytest.mark.parametrize("verb", ["run", "sweep", "compare"])
def test_a_scenario_sweep_or_comparison_that_is_not_a_regular_file_is_one_line(tmp_path, verb, make, found):
    path = tmp_path / "a.toml"
    make(path)
    proc = run_cli(verb, path, "--out", tmp_path / "out", timeout=DEADLINE)
    one_line_error(proc, str(path), found)


def test_replay_refuses_dev_zero_at_its_first_bytes_and_streams_a_log_from_a_pipe(tmp_path):
    """R1: `ftstab replay /dev/zero` read until the OOM killer (23 GB); a log read from a pipe still works."""
    proc = run_cli("replay", "/dev/zero", timeout=DEADLINE)
    one_line_error(proc, "/dev/zero", "expected an MCAP log")
    assert run_cli("run", "cart_r2_robust", "--set", "sim.duration=0.3", "--out", tmp_path).returncode == 0
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    with open(tmp_path / "cart_r2_robust.mcap", "rb") as log:
        piped = subprocess.run([shutil.which("cat") or "cat"], stdin=log, capture_output=True).stdout
    proc = subprocess.run([os.sys.executable, "-m", "ftstab_mj", "replay", "/dev/stdin"], input=piped,
                          capture_output=True, env=env, cwd=ROOT, timeout=DEADLINE)
    assert proc.returncode == 0 and b"recorded metrics: identical" in proc.stdout, proc.stderr


def _replay_piped(feed, *args, cap=None):
    """`ftstab replay - ARGS` reading feed() (an iterable of bytes, maybe endless) from a pipe, its address
    space capped at ``cap`` bytes (RLIMIT_AS); (exit code, stdout, stderr, wall s)."""
    import resource
    import threading
    import time

    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    limit = None if cap is None else (lambda: resource.setrlimit(resource.RLIMIT_AS, (cap, cap)))
    t0 = time.monotonic()
    proc = subprocess.Popen([os.sys.executable, "-m", "ftstab_mj", "replay", "-", *args], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, cwd=ROOT, preexec_fn=limit)

    def write():
        try:
            for part in feed():
                proc.stdin.write(part)
            proc.stdin.close()
        except (BrokenPipeError, ValueError):  # the reader stopped reading: what the test wants to see
            pass

    writer = threading.Thread(target=write, daemon=True)
    writer.start()
    out, err = proc.stdout.read(), proc.stderr.read()
    proc.wait(timeout=DEADLINE)
    return proc.returncode, out.decode(), err.decode(), time.monotonic() - t0


def test_replay_from_a_pipe_is_replay_of_the_file(tmp_path):
    """`ftstab replay -` (standard input) gives what replay of the file gives: the same JSON metrics and,
    for a log cut short, the same warning, for a log with a flipped byte the same damage line; the
    printed report differs only by the name of the log."""
    assert run_cli("run", "cart_r2_robust", "--set", "sim.duration=2.5", "--out", tmp_path).returncode == 0
    log = tmp_path / "cart_r2_robust.mcap"
    cut, flipped = tmp_path / "cut.mcap", tmp_path / "flipped.mcap"
    whole = log.read_bytes()
    cut.write_bytes(whole[:len(whole) * 2 // 3])  # a run killed mid-way: 2 of 3 chunks whole
    middle = len(whole) // 2  # inside the second chunk's compressed samples
    flipped.write_bytes(whole[:middle] + bytes([whole[middle] ^ 0x10]) + whole[middle + 1:])
    for path, exit_code in ((log, 0), (cut, 0), (flipped, 2)):
        data = path.read_bytes()
        for args in (("--json",), ()):
            code, out, err, _ = _replay_piped(lambda: [data], *args)
            ref = run_cli("replay", path, *args)
            assert code == ref.returncode == exit_code, err
            assert out == ref.stdout.replace(str(path), "-") and err == ref.stderr.replace(str(path), "-"), path
    assert "truncated log" in run_cli("replay", cut).stderr and "damaged log" in run_cli("replay", flipped).stderr


def test_garbage_from_a_pipe_is_refused_at_once_in_bounded_memory():
    """Endless garbage on standard input (random bytes, with and without MCAP's magic in front, and zeros
    after it): one line, exit 2, within seconds, in a process whose address space is capped at 1 GiB (the
    reader once held all a pipe gave: `ftstab replay /dev/urandom` reached 21 GB)."""
    import random

    from ftstab_mj.logs.reader import MCAP_MAGIC

    def endless(head, byte=None):
        rng = random.Random(38)
        return lambda: (x for k in range(10 ** 9) for x in ([head] if k == 0 else []) + [
            bytes(1 << 20) if byte == 0 else rng.randbytes(1 << 20)])

    for head, byte, says in ((b"", None, "expected an MCAP log"), (MCAP_MAGIC, None, "unknown record opcode"),
                             (MCAP_MAGIC, 0, "unknown record opcode 0x00")):
        code, out, err, wall = _replay_piped(endless(head, byte), cap=1 << 30)
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1 and lines[0].startswith("error: -: ") and says in lines[0], err
        assert out == "" and wall < 20, (head, wall)
    header = MCAP_MAGIC + bytes([0x01]) + (1 << 40).to_bytes(8, "little")  # a header record of 1 TiB
    code, _, err, _ = _replay_piped(lambda: [header], cap=1 << 30)
    assert code == 2 and "declares 1099511627776 bytes, more than a log read as it streams accepts" in err, err


def test_the_limits_table_is_one_table_that_the_checks_read():
    from ftstab_mj.config import limits, validate
    from ftstab_mj.logs import reader
    from ftstab_mj.scenario import plugins
    from ftstab_mj.studies import montecarlo

    assert validate.MAX_FILE_BYTES is limits.MAX_FILE_BYTES and validate.MAX_SAMPLES is limits.MAX_SAMPLES
    assert reader.MAX_CHUNK_BYTES is limits.MAX_CHUNK_BYTES and reader.MAX_RECORD_BYTES is limits.MAX_RECORD_BYTES and montecarlo.MAX_STATES is limits.MAX_STATES
    assert plugins.MAX_PLUGIN_BYTES is limits.MAX_PLUGIN_BYTES
    assert limits.markdown().count("\n") == len(limits.TABLE) + 1


def test_montecarlo_with_v1_beyond_float_range_says_no_bound_and_writes_strict_json(tmp_path):
    """W3: `--box 1e150` made V1(z0) infinite; the command said "bound applies" and wrote a bare NaN (not JSON)."""
    import json

    proc = run_cli("montecarlo", "cart_r2_nominal", "--states", "4", "--box", "1e150,1e150", "--set", "sim.duration=0.5",
                   "--out", tmp_path, timeout=DEADLINE)
    assert proc.returncode == 0, proc.stderr
    assert "(bound does not apply)" in proc.stdout and "V1(z0) is not a finite number for 4 state(s)" in proc.stdout
    summary = json.loads((tmp_path / "montecarlo.json").read_text(),
                         parse_constant=lambda c: pytest.fail(f"{c} in the JSON"))
    assert summary["bound_applies"] is False and summary["worst"]["settle_time"] is None


def test_a_comparison_grid_with_a_repeated_value_is_refused_and_a_fit_counts_each_value_once(tmp_path):
    """W1: `ftstab compare` fitted its log-log slope through duplicate grid values (counted twice)."""
    from ftstab_mj.studies.compare import fit_slopes

    path = tmp_path / "dup.toml"
    path.write_text(f'''name = "dup"
description = "a grid value twice"
scenario = "{ROOT / "scenarios" / "cart_r2_robust.toml"}"
[grid]
"sim.period" = [1e-3, 2e-3, 1e-3]
[[laws]]
label = "linear"
controller = {{ law = "linear", poles = [-3.0, -3.0] }}
''')
    proc = run_cli("compare", path, "--out", tmp_path / "o", timeout=DEADLINE)
    one_line_error(proc, str(path), 'grid."sim.period": expected distinct values', "repeated 0.001")
    rows = [{"label": "a", "status": "completed", "h": h, "final_abs_z1": y}
            for h, y in ((1.0, 1.0), (10.0, 10.0), (100.0, 1000.0), (100.0, 1000.0))]
    # through (0, 0), (1, 1), (2, 3) in logs: 1.5; the repeated point counted twice gave 1.545
    assert fit_slopes(rows, "h")[0]["slope_z1"] == pytest.approx(1.5)


@pytest.mark.parametrize("delay", ["1e9", "1e8", "1000001"])
def test_a_sensor_delay_beyond_its_limit_is_one_line_before_anything_is_allocated(tmp_path, delay):
    """R2: a delay of 1e9 ended in a traceback, 1e8 allocated 3.2 GB before anything ran."""
    proc = run_cli("run", "cart_r2_output_feedback", "--set", f"loops.cart.sensor.delay={delay}", "--out", tmp_path / "o",
                   timeout=DEADLINE)
    one_line_error(proc, "loops.cart.sensor.delay: expected a whole number of control periods in [0, 1e6]")
    assert not (tmp_path / "o").exists()
