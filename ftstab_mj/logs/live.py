"""Live viewing of a run as it happens: a Foxglove WebSocket server that mirrors the MCAP log, the
choice of a Rerun viewer, and real-time pacing.

- :class:`FoxgloveServer` (``ftstab run --foxglove``): a foxglove-sdk WebSocket server. The MCAP
  sink hands it its writer (:meth:`FoxgloveServer.mirror`), so every channel, schema and message
  the log gets is also published, byte for byte and at the same log time (sim time in ns): a
  Foxglove app connected to the server shows what it shows of the file, with the same layout.
  The one-off messages (``/scene``, ``/scenario``, ``/run_info``, ``/metrics``) are sent again to
  each client that subscribes later (a WebSocket server keeps no history). It speaks both names of
  the protocol: ``foxglove.sdk.v1`` (foxglove-sdk's, the Foxglove app) and ``foxglove.websocket.v1``
  (older clients: Lichtblick, ws-protocol), the same protocol under its former name
  (:class:`_SubprotocolRelay`).
- :func:`rerun_target` (``ftstab run --live``): "spawn" a native Rerun viewer when there is a display,
  else "serve" (a ``rerun --serve-web`` server: web viewer and gRPC, logs/rerun_sink.start_viewer).
- :class:`Pacer` (``--realtime``): a sink that holds each batch until the wall clock has reached
  its last sample's sim time, so the stream follows the clock; it measures how far it lagged.

Only a live run imports foxglove's server or sleeps; the files are written as without it.
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np

REALTIME_RATE = 30.0  # Hz of wall time at which a --realtime run hands batches on (the viewers' refresh)
LATCHED = ("/scene", "/scenario", "/run_info", "/metrics")  # topics with one message: resent to late subscribers
RERUN_SCHEMES = ("rerun://", "rerun+http://", "rerun+https://")  # the gRPC URLs rerun-sdk 0.41 accepts
BACKLOG = 1 << 16  # messages buffered per client: more than a whole batch (1000 samples) and its poses


def has_display() -> bool:
    """Whether a native viewer window can open here (an X11 or Wayland display, or macOS / Windows)."""
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) or sys.platform in ("darwin", "win32")


def rerun_target(live) -> str | None:
    """The RerunSink ``live`` value of a --live choice: None/False (no live view), True or "auto"
    ("spawn" with a display, else "serve"), "spawn", "serve", or a rerun+http:// URL (kept).
    Anything else raises ValueError before a server or a log is opened (rerun-sdk would refuse it later,
    with a log already half-written)."""
    if live is None or live is False:
        return None
    if live is True or live == "auto":
        return "spawn" if has_display() else "serve"
    if isinstance(live, str) and (live in ("spawn", "serve") or live.startswith(RERUN_SCHEMES)):
        return live
    raise ValueError(f"expected spawn, serve or a rerun+http:// URL, got {live!r}")


def realtime_batch(period: float) -> int:
    """Samples per batch of a --realtime run: 1 / REALTIME_RATE s of sim time (at least one sample)."""
    return max(1, int(round(1.0 / (REALTIME_RATE * period))))


class Pacer:
    """A sink that paces a run to the wall clock: :meth:`write` returns once the wall time since the
    first sample was handed on has reached the batch's last sample time minus the first's (the
    clock starts at the first batch: opening the logs and the viewers' start are not counted). Put
    it first among the sinks, so the others (and the viewers) get each batch when its time has come.

    After the run: ``lags`` (s), per batch, how far the wall clock was past the batch's time when it
    was handed on (0 when the run keeps up: then the wait absorbed the difference), ``wall`` the
    wall time of the run and ``sim`` its simulated time. Reports them on ``stream`` at close.
    """

    def __init__(self, stream=None):
        self.stream = stream if stream is not None else sys.stderr
        self.lags: list[float] = []
        self.wall = self.sim = 0.0

    def open(self, info) -> None:
        self._start = None

    def write(self, batch) -> None:
        t_batch = next(iter(batch.loops.values()))["t"]
        if self._start is None:
            self._t0 = float(t_batch[0])
            self._start = time.monotonic()
        t = float(t_batch[-1]) - self._t0
        while (ahead := t - (time.monotonic() - self._start)) > 0:
            time.sleep(ahead)
        self.lags.append(time.monotonic() - self._start - t)
        self.sim = t

    def close(self, status: str, metrics: dict, message: str = "") -> None:
        if self._start is not None:
            self.wall = time.monotonic() - self._start
            self.stream.write(f"realtime: {self.sim:.3f} s simulated in {self.wall:.3f} s of wall time; batches "
                              f"handed on at most {1e3 * max(self.lags):.1f} ms after their time "
                              f"(median {1e3 * float(np.median(self.lags)):.1f} ms)\n")
            self.stream.flush()


class FoxgloveServer:
    """A Foxglove WebSocket server on ``host``:``port`` (0: a free port), in its own foxglove Context
    (nothing else the process logs with foxglove reaches it). :meth:`mirror` wraps the MCAP sink's
    writer; :meth:`stop` ends the server.

    The server starts listening once the log has all its channels (at the first batch; ``say`` then
    tells its address): foxglove-sdk 0.30 advertises a channel created while a client is connected
    before it can take a subscription to it, and a client that subscribes at once is refused
    ("attempted to subscribe to unknown channel", seen 3 times in 4 runs on a loaded machine);
    channels that exist when a client connects are not. The port is checked free at construction.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 8765, name: str = "ftstab", say=None):
        import foxglove

        self._foxglove = foxglove
        self._context = foxglove.Context()
        self._channels: dict[str, object] = {}  # topic -> foxglove.Channel
        self._latched: dict[str, tuple[int, bytes]] = {}  # topic -> (log time, message)
        self._resend: set[str] = set()  # latched topics a client subscribed to since they were last sent
        self.host, self._port, self.name, self._say = host, port, name, say
        self._server = self._relay = None
        self._refused = False  # start() could not listen (then it never tries again)
        if port:
            _check_bindable(host, port)

    def start(self) -> None:
        """Listen (once): the channels made so far are advertised whole to every client. A refusal is
        raised once: the log it mirrors still closes whole (its status says why the run stopped)."""
        if self._server is not None or self._refused:
            return
        fg, outer = self._foxglove, self

        class _Listener(fg.ServerListener):
            def on_subscribe(self, client, channel) -> None:
                if channel.topic in LATCHED:  # sent with the next batch (not from the server's thread)
                    outer._resend.add(channel.topic)

        # foxglove-sdk 0.30 answers HTTP 400 to the former name: it listens on a private loopback port
        # and the relay on the user's, renaming the subprotocol in the handshake
        server = fg.start_server(name=self.name, host="127.0.0.1", port=0, context=self._context,
                                 server_listener=_Listener(), message_backlog_size=BACKLOG)
        try:  # the port was free at construction; another program may have taken it since
            self._relay = _SubprotocolRelay(self.host, self._port, ("127.0.0.1", server.port))
        except OSError as exc:
            from ftstab_mj.config.errors import LogError

            server.stop()
            self._refused = True
            raise LogError(f"foxglove {self.host}:{self._port}: expected an address to serve on, found "
                           f"{exc.strerror or exc} (taken after the run was set up)") from None
        self._server = server
        if self._say is not None:
            self._say(f"foxglove: serving {self.url} while the run lasts (Foxglove: Open connection > Foxglove "
                      f"WebSocket, or {self.app_url})")

    @property
    def port(self) -> int:
        return self._relay.port if self._server is not None else self._port

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    @property
    def app_url(self) -> str:
        """The Foxglove web app opening :attr:`url` (the relay's, not the SDK server's private port)."""
        from urllib.parse import quote

        return "https://app.foxglove.dev?ds=foxglove-websocket&ds.url=" + quote(self.url, safe="")

    def mirror(self, writer):
        """The MCAP sink's writer (logs/mcap_file.McapFile), wrapped so that what it writes is also published."""
        return _Mirror(writer, self)

    def _channel(self, topic: str, encoding: str, schema) -> None:
        fg = self._foxglove
        self._channels[topic] = fg.Channel(topic, schema=fg.Schema(name=schema[0], encoding=schema[1], data=schema[2]),
                                           message_encoding=encoding, context=self._context)

    def _publish(self, topic: str, log_times, datas) -> None:
        channel = self._channels[topic]
        for t, data in zip(np.asarray(log_times, dtype=np.int64).tolist(), datas):
            channel.log(data, log_time=t)
        if topic in LATCHED and len(datas):
            self._latched[topic] = (int(np.asarray(log_times)[-1]), bytes(datas[-1]))
        self._send_latched()

    def _send_latched(self) -> None:
        """Send the one-off messages again to the clients that subscribed after they went out."""
        while self._resend:
            topic = self._resend.pop()
            if topic in self._latched:
                t, data = self._latched[topic]
                self._channels[topic].log(data, log_time=t)

    def stop(self) -> None:
        if self._server is not None:
            # foxglove-sdk 0.30's stop drops what its per-client senders still queue (the run's last
            # /metrics, lost 1 time in 3 on a loaded machine) and it has no flush: a client connected
            # gets a bounded grace first. Then the server: what it sent still crosses the relay, whose
            # connections end when the server closes them; then the relay, bounded
            if self._relay.connected():
                time.sleep(SEND_GRACE_S)
            self._server.stop()
            self._relay.stop(drain=RELAY_DRAIN_S)
            self._server = None


SEND_GRACE_S = 0.5  # s a connected client gets, at stop, to receive what the server still queues
RELAY_DRAIN_S = 2.0  # s the relay waits, at stop, for the clients to get what the server sent last
SDK_SUBPROTOCOL = "foxglove.sdk.v1"  # what foxglove-sdk 0.30's server accepts
FORMER_SUBPROTOCOL = "foxglove.websocket.v1"  # the same protocol's former name, which it refuses
_MAX_HEAD = 64 * 1024  # bytes of an HTTP request or response head (a handshake is < 1 kB)


def _rename_subprotocol(head: bytes, old: str, new: str) -> tuple[bytes, bool]:
    """``head`` (an HTTP head, CRLF lines) with ``old`` replaced by ``new`` in its Sec-WebSocket-Protocol
    header when that header offers ``old`` and not ``new``; (head, whether it was renamed)."""
    lines = head.split(b"\r\n")
    for k, line in enumerate(lines):
        name, sep, value = line.partition(b":")
        if sep and name.strip().lower() == b"sec-websocket-protocol":
            offered = [v.strip() for v in value.decode("latin-1").split(",")]
            if old in offered and new not in offered:
                lines[k] = name + b": " + ", ".join(new if v == old else v for v in offered).encode("latin-1")
                return b"\r\n".join(lines), True
    return head, False


class _SubprotocolRelay:
    """A TCP relay from ``host``:``port`` (0: a free port) to ``upstream`` (the SDK's server) that lets a
    client offering only ``foxglove.websocket.v1`` in: its handshake reaches the server offering
    ``foxglove.sdk.v1`` and the server's answer returns naming ``foxglove.websocket.v1`` (the accept
    key does not depend on it); every other byte passes unchanged, both ways. One thread accepts,
    one per connection relays."""

    def __init__(self, host: str, port: int, upstream: tuple[str, int]):
        import socket
        import threading

        self._upstream = upstream
        self._listener = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET)
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self._listener.bind((host, port))
            self._listener.listen(16)
        except OSError:
            self._listener.close()
            raise
        self.port = self._listener.getsockname()[1]
        self._open: set = set()  # the sockets of live connections, closed at stop
        self._lock = threading.Lock()
        self._stopped = False
        self._thread = threading.Thread(target=self._accept, name="foxglove-relay", daemon=True)
        self._thread.start()

    def _accept(self) -> None:
        import threading

        while True:
            try:
                client, _ = self._listener.accept()
            except OSError:  # closed by stop
                return
            threading.Thread(target=self._serve, args=(client,), name="foxglove-relay-conn", daemon=True).start()

    def _serve(self, client) -> None:
        import selectors
        import socket

        upstream = None
        try:
            with self._lock:
                if self._stopped:
                    return
                self._open.add(client)
            head, rest = _read_head(client)
            head, renamed = _rename_subprotocol(head, FORMER_SUBPROTOCOL, SDK_SUBPROTOCOL)
            upstream = socket.create_connection(self._upstream, timeout=30)
            upstream.settimeout(None)
            with self._lock:
                self._open.add(upstream)
            upstream.sendall(head + rest)
            head, rest = _read_head(upstream)
            if renamed:
                head = _rename_subprotocol(head, SDK_SUBPROTOCOL, FORMER_SUBPROTOCOL)[0]
            client.sendall(head + rest)
            sel = selectors.DefaultSelector()
            sel.register(client, selectors.EVENT_READ, upstream)
            sel.register(upstream, selectors.EVENT_READ, client)
            open_sides = 2
            while open_sides:
                for key, _ in sel.select():
                    data = key.fileobj.recv(65536)
                    if data:
                        key.data.sendall(data)
                        continue
                    # one side is done sending: pass the half-close on and keep reading the other until
                    # it ends too. Closing both at once would reset a connection whose peer still sends
                    # (a WebSocket close reply), and a reset drops what it had not read yet: the last
                    # messages of the run (/metrics)
                    sel.unregister(key.fileobj)
                    open_sides -= 1
                    try:
                        key.data.shutdown(socket.SHUT_WR)
                    except OSError:
                        pass
        except (OSError, ValueError):  # a client gone, a malformed head, or stop closing the sockets
            return
        finally:
            for s in (client, upstream):
                if s is not None:
                    with self._lock:
                        self._open.discard(s)
                    s.close()

    def connected(self) -> bool:
        """Whether a client connection is open."""
        with self._lock:
            return bool(self._open)

    def stop(self, drain: float = 0.0) -> None:
        """Close the listener and every connection; first wait up to ``drain`` s for the connections to
        end by themselves (the upstream server closed them after its last messages)."""
        import socket

        deadline = time.monotonic() + drain
        while time.monotonic() < deadline:
            with self._lock:
                if not self._open:
                    break
            time.sleep(0.01)
        with self._lock:
            self._stopped = True
            live = list(self._open)
        try:
            self._listener.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self._listener.close()
        for s in live:
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        self._thread.join(timeout=5)


def _read_head(sock) -> tuple[bytes, bytes]:
    """(an HTTP head up to and excluding its blank line's CRLF CRLF, what followed it, the CRLF CRLF first)
    read from ``sock``; ValueError past _MAX_HEAD bytes or when the peer closes first."""
    buf = b""
    while b"\r\n\r\n" not in buf:
        data = sock.recv(4096)
        if not data or len(buf) > _MAX_HEAD:
            raise ValueError("no HTTP head")
        buf += data
    head, _, rest = buf.partition(b"\r\n\r\n")
    return head, b"\r\n\r\n" + rest


def _check_bindable(host: str, port: int) -> None:
    """Raise OSError when ``host``:``port`` cannot be listened on (in use, not an address of this host)."""
    import socket

    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind((host, port))


class _Mirror:
    """An McapFile whose channels, schemas and messages also go to a :class:`FoxgloveServer`."""

    def __init__(self, writer, server: FoxgloveServer):
        self._writer, self._server = writer, server
        self._schemas: dict[int, tuple[str, str, bytes]] = {}
        self._topics: dict[int, str] = {}

    def __getattr__(self, name):  # start, finish, add_metadata: the file's own
        return getattr(self._writer, name)

    def flush(self) -> None:
        self._writer.flush()
        if any(topic.startswith("/loop/") for topic in self._topics.values()):  # the first batch is in
            self._server.start()

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        sid = self._writer.register_schema(name, encoding, data)
        self._schemas[sid] = (name, encoding, bytes(data))
        return sid

    def register_channel(self, topic: str, message_encoding: str, schema_id: int) -> int:
        cid = self._writer.register_channel(topic, message_encoding, schema_id)
        self._topics[cid] = topic
        self._server._channel(topic, message_encoding, self._schemas[schema_id])
        return cid

    def add_messages(self, channel: int, log_times, datas) -> None:
        self._writer.add_messages(channel, log_times, datas)
        self._server._publish(self._topics[channel], log_times, datas)

    def add_fixed_messages(self, channel: int, log_times, payloads: np.ndarray) -> None:
        self._writer.add_fixed_messages(channel, log_times, payloads)
        blob, size = payloads.tobytes(), payloads.dtype.itemsize
        self._server._publish(self._topics[channel], log_times, [blob[i:i + size] for i in range(0, len(blob), size)])

    def add_message(self, channel: int, log_time: int, data: bytes) -> None:
        self.add_messages(channel, [log_time], [data])


class RerunServer:
    """A ``rerun --serve-web`` process (or one already listening on the port): ``url`` its gRPC
    proxy (rerun+http://...), ``web_url`` its web viewer, ``pid`` the process started (None: reused)."""

    def __init__(self, url: str, web_url: str, pid: int | None):
        self.url, self.web_url, self.pid = url, web_url, pid


def _listening(port: int) -> bool:
    import socket

    with socket.socket() as s:
        s.settimeout(0.2)
        return s.connect_ex(("127.0.0.1", port)) == 0


GRPC_PROBE_TIMEOUT = 2.0  # s for what listens on a --grpc-port (or a --live URL) to answer as a gRPC server
HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + b"\x00\x00\x00\x04\x00\x00\x00\x00\x00"  # + empty SETTINGS


def speaks_grpc(host: str, port: int, timeout: float = GRPC_PROBE_TIMEOUT) -> bool:
    """Whether ``host``:``port`` accepts a connection and answers an HTTP/2 client preface with a frame of its
    own (a gRPC server, as Rerun's, sends its SETTINGS) within ``timeout`` s. A port where nothing listens, a
    socket that never accepts or never answers, another protocol (an HTTP/1 server closes or answers text):
    False. Rerun's own client would wait for ever on those (its flush has no bound)."""
    import socket

    try:
        with socket.create_connection((host, port), timeout=timeout) as s:
            s.settimeout(timeout)
            s.sendall(HTTP2_PREFACE)
            head = b""
            while len(head) < 9:  # a frame header: length (3), type (1), flags (1), stream (4)
                chunk = s.recv(9 - len(head))
                if not chunk:
                    return False
                head += chunk
            return head[3] == 0x04 and head[5:9] == b"\x00\x00\x00\x00"  # SETTINGS on stream 0
    except OSError:  # refused, unreachable, timed out
        return False


def check_rerun_url(url: str, timeout: float = GRPC_PROBE_TIMEOUT) -> None:
    """LogError (one line) unless the Rerun gRPC server at ``url`` (rerun+http://HOST:PORT/...) answers."""
    from urllib.parse import urlsplit

    from ftstab_mj.config.errors import LogError

    try:
        parts = urlsplit(url)
        host, port = parts.hostname, parts.port
    except ValueError:
        host = port = None
    if not host or not port:
        raise LogError(f"--live {url}: expected a Rerun gRPC URL such as rerun+http://127.0.0.1:9876/proxy, found no host and port")
    if not speaks_grpc(host, port, timeout):
        raise LogError(f"--live {url}: expected a Rerun viewer or server answering on {host}:{port}, found none "
                       f"(nothing listens, or no gRPC answer within {timeout:g} s)")


def rerun_binary() -> str | None:
    """The viewer binary rerun-sdk ships (the `rerun` command is a Python wrapper that runs it as a
    child: the process to stop is the binary), or None."""
    try:
        import rerun_cli
    except ImportError:
        return None
    path = os.path.join(os.path.dirname(rerun_cli.__file__), "rerun" + (".exe" if sys.platform.startswith("win") else ""))
    return path if os.path.exists(path) else None


def serve_rerun(grpc_port: int, web_port: int, timeout: float = 20.0) -> RerunServer:
    """Start ``rerun --serve-web`` (the rerun-sdk's own server: a web viewer on ``web_port`` and a
    gRPC proxy on ``grpc_port`` that keeps the data for viewers that connect later), in a session of
    its own so that it outlives the run, unless a server already listens on ``grpc_port`` (then the
    run streams into it). Returns once the gRPC port accepts connections; LogError when it does not."""
    import shutil
    import subprocess

    from ftstab_mj.config.errors import LogError

    from urllib.parse import quote

    url = f"rerun+http://127.0.0.1:{grpc_port}/proxy"  # the web viewer connects to it from the browser's side:
    web_url = f"http://127.0.0.1:{web_port}?url={quote(f'rerun+http://localhost:{grpc_port}/proxy', safe='')}"
    if _listening(grpc_port):
        if not speaks_grpc("127.0.0.1", grpc_port):  # another program's port: Rerun would wait on it for ever
            raise LogError(f"--grpc-port {grpc_port}: expected a free port or a running Rerun server, found the port "
                           f"in use by another program (no gRPC answer within {GRPC_PROBE_TIMEOUT:g} s)")
        return RerunServer(url, web_url, None)
    exe = rerun_binary() or shutil.which("rerun")
    if exe is None:
        raise LogError("--live serve: expected the `rerun` command of rerun-sdk on PATH, found none")
    proc = subprocess.Popen([exe, "--serve-web", "--port", str(grpc_port), "--web-viewer-port", str(web_port)],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    deadline = time.monotonic() + timeout
    while not _listening(grpc_port):
        if proc.poll() is not None:
            raise LogError(f"--live serve: `rerun --serve-web --port {grpc_port} --web-viewer-port {web_port}` "
                           f"exited with status {proc.returncode} (a port in use?)")
        if time.monotonic() > deadline:
            proc.kill()
            raise LogError(f"--live serve: expected the Rerun server to listen on port {grpc_port} within "
                           f"{timeout:g} s, found it silent (stopped it)")
        time.sleep(0.05)
    return RerunServer(url, web_url, proc.pid)


class LiveView:
    """What ``ftstab run --live/--foxglove/--realtime`` (and ``ftstab_mj.run(live=...)``) add to a
    run, started before it (a refused port is an error before any log exists):

    rerun: a --live choice (see :func:`rerun_target`); "serve" starts the server here and the
    RerunSink streams to its URL (:attr:`rerun`). foxglove: (host, port) of a Foxglove server
    (:attr:`foxglove`, for McapSink(live=)). realtime: pace the run (:attr:`pacer`, the first sink)
    in batches of 1 / REALTIME_RATE s. say: where the addresses are told (one line each).
    """

    def __init__(self, rerun=None, foxglove=None, realtime: bool = False, grpc_port: int = 9876,
                 web_port: int = 9090, say=None):
        say = say or (lambda text: print(text, file=sys.stderr, flush=True))
        self.rerun = rerun_target(rerun)
        self.foxglove = None
        self.pacer = Pacer() if realtime else None
        if self.rerun == "serve":
            server = serve_rerun(grpc_port, web_port)
            self.rerun = server.url
            kept = (f"started as pid {server.pid}; it keeps the data for viewers that connect later, until "
                    f"you stop it: kill {server.pid}") if server.pid else "a server already running there"
            say(f"rerun: streaming to {server.url}: open {server.web_url} in a browser, or run "
                f"`rerun {server.url}` ({kept})")
        elif self.rerun == "spawn":
            say("rerun: streaming to a native Rerun viewer (started unless one is open)")
        elif self.rerun is not None:
            check_rerun_url(self.rerun)  # nothing answering there: one line now, not a run that never ends
            say(f"rerun: streaming to {self.rerun}")
        if foxglove is not None:
            self.foxglove = FoxgloveServer(*foxglove, say=say)
            if not realtime:
                say("foxglove: a run not paced by --realtime may be over before a Foxglove app connects")

    def batch_size(self, period: float, default: int = 1000) -> int:
        """Samples per batch: ``default`` unless paced (then 1 / REALTIME_RATE s of sim time)."""
        return realtime_batch(period) if self.pacer is not None else default

    def sinks(self) -> tuple:
        """The sinks to put before the logs' (the pacer), empty when not paced."""
        return (self.pacer,) if self.pacer is not None else ()

    def stop(self) -> None:
        """Stop the Foxglove server (the Rerun viewer or server is a process of its own and stays)."""
        if self.foxglove is not None:
            self.foxglove.stop()
            self.foxglove = None
