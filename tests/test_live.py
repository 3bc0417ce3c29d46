"""Live viewing (``ftstab run --live/--foxglove/--realtime``, ``ftstab_mj.run(live=...)``), through
real servers and clients on free local ports: a Foxglove WebSocket client receives the MCAP log's
messages byte for byte, a Rerun client connected to the served recording receives every sample,
the files are the same as without live viewing, a paced run takes at least its simulated time, and
Ctrl-C during a live run leaves consistent logs."""

import base64
import json
import os
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect  # imported here: not between the run's start and the client's connection

from conftest import free_port, rrd_rows, run_cli, start_cli, wait_for_samples
from ftstab_mj.logs.reader import read_log

SCENARIO = "cart_r2_robust"
# the protocol's two names: foxglove-sdk's (the Foxglove app) and the former one of older clients (Lichtblick,
# ws-protocol), which foxglove-sdk 0.30's server refuses with HTTP 400 and the live server's relay lets in
SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")


def _mcap_messages(path) -> dict:
    """{topic: {log time ns: [message bytes]}} and {topic: (schema name, encoding, data)} read with the plain mcap reader."""
    messages, schemas = {}, {}
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            messages.setdefault(channel.topic, {}).setdefault(message.log_time, []).append(message.data)
            schemas[channel.topic] = (schema.name, schema.encoding, schema.data, channel.message_encoding)
    return messages, schemas


def _read_line(stream, prefix: str, timeout: float = 120.0) -> str:
    """The first line of ``stream`` (a child's stderr) that starts with ``prefix``; what came before on failure."""
    seen = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = stream.readline()
        if not line:
            break
        if line.startswith(prefix):
            return line
        seen.append(line)
    raise AssertionError(f"no line starting with {prefix!r}; got: {''.join(seen)[-2000:]}")


def _foxglove_client(url: str, subprotocol: str = SUBPROTOCOLS[0], timeout: float = 120.0):
    """Subscribe to every channel the server advertises, offering only ``subprotocol``; return (channels
    {id: advertisement}, messages [(channel id, log time, payload)]) received until the server closes
    the connection."""
    channels, received, subs = {}, [], {}
    deadline = time.monotonic() + timeout
    with connect(url, subprotocols=[subprotocol], open_timeout=30) as ws:
        assert ws.subprotocol == subprotocol
        while time.monotonic() < deadline:
            try:
                frame = ws.recv(timeout=max(0.1, deadline - time.monotonic()))
            except (ConnectionClosed, TimeoutError):
                break
            if isinstance(frame, str):
                msg = json.loads(frame)
                if msg["op"] == "advertise":
                    new = [c for c in msg["channels"] if c["id"] not in channels]
                    for c in new:
                        channels[c["id"]] = c
                        subs[len(subs) + 1] = c["id"]
                    ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                        {"id": sid, "channelId": cid} for sid, cid in subs.items() if cid in {c["id"] for c in new}]}))
            elif frame[0] == 1:  # message data: opcode, subscription id (u32), log time (u64), payload
                sid, log_time = struct.unpack_from("<IQ", frame, 1)
                received.append((subs[sid], log_time, bytes(frame[13:])))
    return channels, received


@pytest.mark.parametrize("subprotocol", SUBPROTOCOLS)
def test_foxglove_client_receives_the_mcap_logs_messages_as_they_are_written(tmp_path, subprotocol):
    """A run served with --foxglove on a free port (port 0) and paced with --realtime: a WebSocket
    client (of either subprotocol) that subscribes to every advertised channel gets the MCAP log's channels with the same
    schemas, and every message it gets is one the log holds at that log time, byte for byte; from
    the first loop sample it gets to the end of the run it gets every one (none dropped, in order);
    the loop messages decode (the advertised schema, mcap-protobuf-support) to the logged samples."""
    from mcap.records import Schema
    from mcap_protobuf.decoder import DecoderFactory

    # 3 s paced: time for the client to connect on a loaded machine (seen 1.2 s after the server's line)
    proc = start_cli("run", SCENARIO, "--out", tmp_path, "--set", "sim.duration=3", "--realtime",
                     "--foxglove", "127.0.0.1:0")
    try:
        line = _read_line(proc.stderr, "foxglove: serving ")
        url = line.split()[2]
        channels, received = _foxglove_client(url, subprotocol)
        out, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    assert "realtime: " in err
    logged, schemas = _mcap_messages(tmp_path / f"{SCENARIO}.mcap")
    by_topic = {c["topic"]: c for c in channels.values()}
    assert set(by_topic) == set(logged)  # the same channels: /loop/cart, /tf, /scene, /scenario, /run_info, /metrics
    for topic, c in by_topic.items():
        name, encoding, data, message_encoding = schemas[topic]
        assert (c["schemaName"], c["schemaEncoding"], c["encoding"]) == (name, encoding, message_encoding)
        advertised = base64.b64decode(c["schema"]) if c["schemaEncoding"] == "protobuf" else c["schema"].encode()
        assert advertised == data, topic
    got = {}
    for cid, log_time, payload in received:
        topic = channels[cid]["topic"]
        assert payload in logged[topic].get(log_time, []), (topic, log_time)
        got.setdefault(topic, []).append((log_time, payload))
    # the client connected while the run was starting: it saw the samples (and the scene, sent again to it)
    assert {"/loop/cart", "/tf", "/scene", "/metrics"} <= set(got), set(got)
    loop = by_topic["/loop/cart"]
    decoder = DecoderFactory().decoder_for("protobuf", Schema(id=1, name=loop["schemaName"], encoding="protobuf",
                                                              data=base64.b64decode(loop["schema"])))
    log = read_log(tmp_path / f"{SCENARIO}.mcap")
    t_ns = np.rint(log.loops["cart"]["t"] * 1e9).astype(np.int64)
    samples = got["/loop/cart"]
    # how many it gets depends on when it connected (the load of the machine: 279 of 1500 once);
    # from its first on it gets every sample, in order, to the end of the run
    first = int(np.searchsorted(t_ns, samples[0][0]))
    assert [log_time for log_time, _ in samples] == t_ns[first:].tolist(), (first, len(samples), len(t_ns))
    for log_time, payload in samples[:: max(1, len(samples) // 50)]:
        i = int(np.searchsorted(t_ns, log_time))
        msg = decoder(payload)
        assert msg.t == log.loops["cart"]["t"][i] and list(msg.z) == log.loops["cart"]["z"][i].tolist()
        assert (msg.u, msg.V1) == (log.loops["cart"]["u"][i], log.loops["cart"]["V1"][i])


def test_live_logs_are_byte_identical_to_the_same_run_without(tmp_path):
    """--foxglove (no client) and --live to a Rerun server leave an MCAP file identical byte for
    byte to the one of a run without them (the MCAP log has no wall-clock time in it), and an .rrd
    holding the same samples; the Rerun server received them all too."""
    plain, live = tmp_path / "plain", tmp_path / "live"
    assert run_cli("run", SCENARIO, "--out", plain, "--set", "sim.duration=1", "--rrd").returncode == 0
    port = free_port()
    got = tmp_path / "received.rrd"
    receiver = _receiver(port, got)
    try:
        _wait_listening(port)
        done = run_cli("run", SCENARIO, "--out", live, "--set", "sim.duration=1", "--foxglove", "127.0.0.1:0",
                       "--live", f"rerun+http://127.0.0.1:{port}/proxy", "--rrd")
        assert done.returncode == 0, done.stderr
        assert f"rerun: streaming to rerun+http://127.0.0.1:{port}/proxy" in done.stderr
        _wait_rows(got, "/loop/cart/V1/log10_V1", 1000)
    finally:
        _stop(receiver)
    name = f"{SCENARIO}.mcap"
    assert (live / name).read_bytes() == (plain / name).read_bytes()
    rrd = f"{SCENARIO}.rrd"
    for entity in ("/loop/cart/V1/log10_V1", "/loop/cart/control", "/world/cart"):
        assert rrd_rows(live / rrd, entity) == rrd_rows(plain / rrd, entity) == rrd_rows(got, entity), entity


def _receiver(port: int, path) -> subprocess.Popen:
    """A `rerun --port PORT --save PATH` receiver in its own session: `rerun` is a Python wrapper
    around the viewer binary, and Ctrl-C must reach both, as a terminal's does (:func:`_stop`).
    Its log output is dropped (a pipe nobody reads while the test runs could fill and stall it)."""
    return subprocess.Popen([str(Path(sys.executable).parent / "rerun"), "--port", str(port), "--save", str(path)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)


def _stop(receiver: subprocess.Popen) -> None:
    """Ctrl-C the receiver's process group; it ends its file and exits. What the tests check of the
    file was waited for before (:func:`_wait_rows`), so a receiver that is slow to shut down on a
    loaded machine is killed after 60 s rather than failing a test about our logs."""
    os.killpg(receiver.pid, signal.SIGINT)
    try:
        receiver.wait(timeout=60)
    except subprocess.TimeoutExpired:
        os.killpg(receiver.pid, signal.SIGKILL)
        receiver.wait()


def _wait_listening(port: int, timeout: float = 60.0) -> None:
    from ftstab_mj.logs.live import _listening

    deadline = time.monotonic() + timeout
    while not _listening(port):
        assert time.monotonic() < deadline, f"nothing listens on port {port}"
        time.sleep(0.05)


def _wait_rows(path, entity: str, at_least: int, timeout: float = 60.0) -> None:
    """Wait until the .rrd a Rerun receiver saves holds ``at_least`` rows of ``entity`` (it writes as data comes)."""
    deadline = time.monotonic() + timeout
    while not (path.exists() and rrd_rows(path, entity) >= at_least):
        assert time.monotonic() < deadline, f"{path}: fewer than {at_least} rows of {entity}"
        time.sleep(0.2)


def test_live_serve_keeps_the_run_for_a_viewer_that_connects_afterwards(tmp_path):
    """--live serve on free ports starts a `rerun --serve-web` server that outlives the run; a Rerun
    client that connects once the run is over (`rerun URL --save`) receives every sample. Without
    --rrd: the viewer gets the run, the directory only the MCAP log."""
    grpc, web = free_port(), free_port()
    done = run_cli("run", SCENARIO, "--out", tmp_path / "o", "--set", "sim.duration=1", "--live", "serve",
                   "--grpc-port", grpc, "--web-port", web)
    assert done.returncode == 0, done.stderr
    line = next(x for x in done.stderr.splitlines() if x.startswith("rerun: streaming to "))
    pid = int(line.split("started as pid ")[1].split(";")[0])
    url = f"rerun+http://127.0.0.1:{grpc}/proxy"
    assert url in line and f"http://127.0.0.1:{web}?url=rerun%2Bhttp%3A%2F%2Flocalhost%3A{grpc}%2Fproxy" in line
    got = tmp_path / "viewer.rrd"
    try:
        from urllib.request import urlopen

        with urlopen(f"http://127.0.0.1:{web}/", timeout=30) as page:  # the web viewer is served
            assert page.status == 200
        client = subprocess.Popen([str(Path(sys.executable).parent / "rerun"), url, "--save", str(got),
                                   "--port", str(free_port())], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        _wait_rows(got, "/loop/cart/V1/log10_V1", 1000)
    finally:
        import os

        os.kill(pid, signal.SIGTERM)  # the server this test started (through ftstab run)
    client.communicate(timeout=60)  # its stream ends with the server
    assert rrd_rows(got, "/loop/cart/V1/log10_V1") - 1 == read_log(tmp_path / "o" / f"{SCENARIO}.mcap").n_samples  # + style
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == [f"{SCENARIO}.mcap"]


def test_realtime_takes_at_least_the_simulated_time_and_gives_the_same_samples(capsys):
    """ftstab_mj.run(realtime=True): the wall time of the run is at least its simulated time (the
    span from the first sample to the last: duration less one period; the clock starts when the
    first batch is handed on); the samples are the ones of the unpaced run bit for bit (batches of
    33 samples instead of 1000)."""
    import ftstab_mj

    duration, period = 1.0, 1e-3
    fast = ftstab_mj.run(SCENARIO, overrides={"sim.duration": duration})
    t0 = time.monotonic()
    paced = ftstab_mj.run(SCENARIO, overrides={"sim.duration": duration}, realtime=True)
    wall = time.monotonic() - t0
    assert wall >= duration - period, wall
    report = capsys.readouterr().err
    assert report.startswith("realtime: 0.999 s simulated in "), report
    for f, a in fast.samples["cart"].items():
        np.testing.assert_array_equal(paced.samples["cart"][f], a, err_msg=f)


def test_ctrl_c_during_a_live_paced_run_leaves_consistent_logs(tmp_path):
    """Ctrl-C during `ftstab run --realtime --foxglove`: exit 130, both logs closed "interrupted"
    holding the same samples, recorded metrics equal to the replayed ones."""
    proc = start_cli("run", SCENARIO, "--out", tmp_path, "--set", "sim.duration=60", "--realtime",
                     "--foxglove", "127.0.0.1:0", "--rrd")
    log = tmp_path / f"{SCENARIO}.mcap"
    wait_for_samples(log, size=30_000)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "error: run interrupted" in err and "Traceback" not in err
    data = read_log(log)
    assert data.complete and data.recorded["status"] == "interrupted" and 0 < data.n_samples < 60_000
    assert rrd_rows(tmp_path / f"{SCENARIO}.rrd", "/loop/cart/V1/log10_V1") - 1 == data.n_samples  # + its style row
    replay = run_cli("replay", log)
    assert replay.returncode == 0 and "recorded metrics: identical" in replay.stdout


def test_a_foxglove_port_in_use_is_one_line_exit_2_and_no_log(tmp_path):
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        done = run_cli("run", SCENARIO, "--out", tmp_path, "--foxglove", f"127.0.0.1:{s.getsockname()[1]}")
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stderr.startswith("error: --foxglove 127.0.0.1:") and len(done.stderr.strip().splitlines()) == 1
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("argv", [("--live", SCENARIO), (SCENARIO, "--live", "bogus")],
                         ids=["live-before-scenario", "unknown-target"])
def test_a_bad_live_target_is_one_line_exit_2_and_no_log(tmp_path, argv):
    """--live NAME takes the scenario name as its target (the option's value is optional): the
    parser refuses it in one line; a target rerun-sdk would refuse mid-way (a traceback after
    the logs were opened, before this check) is refused the same way, and by the Python API."""
    import ftstab_mj

    done = run_cli("run", *argv, "--out", tmp_path)
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and "argument --live: expected spawn, serve" in done.stderr
    assert not any(tmp_path.iterdir())
    with pytest.raises(ValueError, match="expected spawn, serve"):
        ftstab_mj.run(SCENARIO, out=tmp_path, live="bogus")
    assert not any(tmp_path.iterdir())


def test_the_python_api_streams_to_a_rerun_viewer_without_writing_a_file(tmp_path):
    """ftstab_mj.run(live=URL) with out=None: the RerunSink streams to the viewer only (no file), and
    the viewer (a `rerun --save` receiver on a free port) gets every sample the run returns."""
    import ftstab_mj

    port = free_port()
    got = tmp_path / "received.rrd"
    receiver = _receiver(port, got)
    try:
        _wait_listening(port)
        res = ftstab_mj.run(SCENARIO, overrides={"sim.duration": 0.5}, live=f"rerun+http://127.0.0.1:{port}/proxy")
        assert res.status == "completed" and res.logs == {}
        _wait_rows(got, "/loop/cart/V1/log10_V1", len(res.samples["cart"]["t"]) + 1)  # + its style row
    finally:
        _stop(receiver)
    assert not any(p.suffix in (".mcap", ".rrd") for p in tmp_path.iterdir() if p != got)


@pytest.mark.parametrize("env, platform, expected", [
    ({"DISPLAY": ":0"}, "linux", "spawn"), ({"WAYLAND_DISPLAY": "wayland-0"}, "linux", "spawn"),
    ({}, "linux", "serve"), ({}, "darwin", "spawn")])
def test_live_true_spawns_a_viewer_with_a_display_and_serves_without(monkeypatch, env, platform, expected):
    from ftstab_mj.logs import live

    for name in ("DISPLAY", "WAYLAND_DISPLAY"):
        monkeypatch.delenv(name, raising=False)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    monkeypatch.setattr(live.sys, "platform", platform)
    assert live.rerun_target(True) == live.rerun_target("auto") == expected
    assert live.rerun_target(False) is None and live.rerun_target("rerun+http://h:1/proxy") == "rerun+http://h:1/proxy"
