"""Every row of the limits table (config/limits.py TABLE) is in the README and has a case here: a value just
beyond the limit through ``main`` (in process: each case costs milliseconds, the file sizes are sparse),
refused in one line naming the file or key, before memory is spent. A row added to the table without a
case fails :func:`test_every_limit_has_a_case`."""

from __future__ import annotations

import os

import pytest

from conftest import ROOT
from ftstab_mj.cli import main
from ftstab_mj.config import limits
from test_plants_user import ASSETS, PENDULUM, _scenario

CART = ROOT / "scenarios" / "cart_r2_robust.toml"


def sparse(path, size: int):
    """A file of ``size`` bytes that takes no disk."""
    with open(path, "wb") as f:
        f.truncate(size)
    return path


def refused(capsys, argv, *words) -> str:
    """main(argv) is exit 2 and one line on stderr holding ``words``; that line."""
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: "), err
    assert all(w in lines[0] for w in words), lines[0]
    return lines[0]


def input_file(tmp_path, capsys):
    path = sparse(tmp_path / "big.toml", limits.MAX_FILE_BYTES + 1)
    refused(capsys, ["run", path, "--out", tmp_path / "o"], str(path))


def mjcf(tmp_path, capsys):
    model = sparse(tmp_path / "big.xml", limits.MAX_MJCF_BYTES + 1)
    path = _scenario(tmp_path, str(model), PENDULUM)
    refused(capsys, ["run", path, "--out", tmp_path / "o"], "plant.model", str(limits.MAX_MJCF_BYTES))


def includes(tmp_path, capsys):
    (tmp_path / "empty.xml").write_text("<mujoco/>")
    text = (ASSETS / "inverted_pendulum.xml").read_text()
    many = '<include file="empty.xml"/>' * (limits.MAX_INCLUDES + 1)
    (tmp_path / "many.xml").write_text(text.replace("<worldbody>", many + "<worldbody>", 1))
    path = _scenario(tmp_path, str(tmp_path / "many.xml"), PENDULUM)
    refused(capsys, ["run", path, "--out", tmp_path / "o"], "plant.model", str(limits.MAX_INCLUDES))


def plugin(tmp_path, capsys):
    sparse(tmp_path / "big_plugin.py", limits.MAX_PLUGIN_BYTES + 1)
    path = tmp_path / "s.toml"
    path.write_text('plugins = ["big_plugin.py"]\n' + CART.read_text())
    refused(capsys, ["run", path, "--out", tmp_path / "o"], "plugins")


def log_file(tmp_path, capsys):
    path = sparse(tmp_path / "huge.mcap", limits.MAX_LOG_BYTES + 1)
    refused(capsys, ["replay", path], str(path))


def small_log(tmp_path, capsys) -> bytes:
    assert main(["run", "cart_r2_robust", "--out", str(tmp_path / "log"), "--set", "sim.duration=0.05"]) == 0
    capsys.readouterr()
    return (tmp_path / "log" / "cart_r2_robust.mcap").read_bytes()


def piped_record(tmp_path, capsys):
    """A record declaring more than a streamed log accepts, read from a FIFO (a pipe), refused at its header."""
    import threading

    fifo = tmp_path / "pipe.mcap"
    os.mkfifo(fifo)
    data = small_log(tmp_path, capsys)[:8] + bytes([0x01]) + (limits.MAX_RECORD_BYTES + 1).to_bytes(8, "little")

    def write():
        try:
            with open(fifo, "wb") as f:
                f.write(data)
        except OSError:
            pass

    writer = threading.Thread(target=write, daemon=True)
    writer.start()
    refused(capsys, ["replay", fifo], str(fifo), str(limits.MAX_RECORD_BYTES + 1))
    writer.join(5)


def chunk(tmp_path, capsys):
    """A log whose first chunk declares more uncompressed bytes than the limit: not decompressed."""
    data = bytearray(small_log(tmp_path, capsys))
    p = 8
    while data[p] != 0x06:  # records: opcode (1 byte), length (8), body; a chunk's body: t0, t1, size, ...
        p += 9 + int.from_bytes(data[p + 1:p + 9], "little")
    data[p + 9 + 16:p + 9 + 24] = (limits.MAX_CHUNK_BYTES + 1).to_bytes(8, "little")
    path = tmp_path / "chunk.mcap"
    path.write_bytes(data)
    code = main(["replay", str(path)])
    err = capsys.readouterr().err
    assert f"declares {limits.MAX_CHUNK_BYTES + 1} uncompressed bytes" in err and "Traceback" not in err, err
    assert code in (1, 2)


def run_set(*sets):
    def case(tmp_path, capsys):
        argv = ["run", CART, "--out", tmp_path / "o"] + [x for s in sets for x in ("--set", s)]
        refused(capsys, argv, str(CART))
        assert not (tmp_path / "o").exists()
    return case


def delay(tmp_path, capsys):
    refused(capsys, ["run", "cart_r2_output_feedback", "--out", tmp_path / "o", "--set",
                     f"loops.cart.sensor.delay={limits.MAX_DELAY_SAMPLES + 1}"], "loops.cart.sensor.delay")


def sweep_rows(tmp_path, capsys):
    path = tmp_path / "big.sweep.toml"
    path.write_text(f'name = "big"\ndescription = "too many runs"\nscenario = "{CART}"\n'
                    f'samples = {limits.MAX_SWEEP_ROWS + 1}\n[set]\n"sim.duration" = 0.01\n'
                    '[draw]\n"loops.cart.disturbance.phase" = {uniform = [0.0, 1.0]}\n')
    refused(capsys, ["sweep", path, "--out", tmp_path / "o"], str(path))


def states(tmp_path, capsys):
    refused(capsys, ["montecarlo", "cart_r2_robust", "--states", limits.MAX_STATES + 1, "--out", tmp_path / "o"],
            "--states")


CASES = {  # TABLE's "what" -> its case
    "scenario, sweep, comparison, expectations file": input_file,
    "MJCF model file": mjcf,
    "each MJCF include": includes,
    "plugin source file": plugin,
    "log file (replay, report, check)": log_file,
    "log from a pipe or standard input": piped_record,
    "decompressed MCAP chunk": chunk,
    "control samples per run": run_set(f"sim.duration={limits.MAX_SAMPLES + 1000}"),  # 1 ms period
    "physics steps per run": run_set("sim.physics_step=1e-5", "sim.period=0.01", "loops.cart.disturbance.freq=0.5",
                                     f"sim.duration={(limits.MAX_STEPS + 10 ** 6) * 1e-5}"),
    "physics steps per control period": run_set("sim.physics_step=1e-6", f"sim.period={(limits.MAX_STEPS_PER_PERIOD + 1) * 1e-6}",
                                                "sim.duration=20"),
    "sensor delay": delay,
    "sweep runs (grid x samples)": sweep_rows,
    "montecarlo --states": states,
    "scenario, sweep, comparison names": run_set("name=" + "a" * 201),
}


def test_every_limit_has_a_case():
    assert set(CASES) == {what for what, *_ in limits.TABLE}


def test_the_readme_shows_the_limits_table():
    text = (ROOT / "README.md").read_text()
    assert limits.markdown() in text


@pytest.mark.parametrize("what", list(CASES))
def test_a_value_beyond_each_limit_is_one_line(tmp_path, capsys, what, monkeypatch):
    monkeypatch.chdir(tmp_path)
    CASES[what](tmp_path, capsys)
