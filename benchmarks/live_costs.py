"""What live viewing costs: CPU time of a whole in-process run with both logs (ftstab_mj.run), plain
against ``foxglove=`` (the WebSocket server publishing every message; no client, then one client
subscribed to every channel, in a process of its own), alternated, medians and ranges.

    python -m benchmarks live_costs [--repeat 5] [--duration 20]

The process CPU time counts the server's own threads; the client's CPU is not counted.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time

CLIENT = r"""
import json, sys, time
from websockets.sync.client import connect
url, n = sys.argv[1], 0
deadline = time.monotonic() + 120
while True:
    try:
        ws = connect(url, subprotocols=["foxglove.sdk.v1"], open_timeout=5)
        break
    except OSError:
        if time.monotonic() > deadline:
            sys.exit(1)
        time.sleep(0.01)
with ws:
    try:
        while True:
            frame = ws.recv(timeout=60)
            if isinstance(frame, str):
                msg = json.loads(frame)
                if msg["op"] == "advertise":
                    ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                        {"id": c["id"], "channelId": c["id"]} for c in msg["channels"]]}))
            else:
                n += 1
    except Exception:
        pass
print(n)
"""


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def one(kind: str, duration: float, out: str) -> tuple[float, int]:
    """(CPU s of the run, messages the client received or -1) for kind plain | server | client."""
    import ftstab_mj

    client, port = None, _free_port()
    if kind == "client":
        client = subprocess.Popen([sys.executable, "-c", CLIENT, f"ws://127.0.0.1:{port}"], stdout=subprocess.PIPE,
                                  text=True)
        time.sleep(0.5)  # its imports done: it is trying to connect
    t0 = time.process_time()
    ftstab_mj.run("cart_r2_robust", out=out, overrides={"sim.duration": duration},
                  foxglove=None if kind == "plain" else ("127.0.0.1", port))
    cpu = time.process_time() - t0
    got = -1
    if client is not None:
        got = int(client.communicate(timeout=120)[0].strip() or 0)
    return cpu, got


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--duration", type=float, default=20.0, help="simulated seconds per run (1 ms period)")
    args = ap.parse_args()
    kinds = ("plain", "server", "client")
    cpu = {k: [] for k in kinds}
    received = []
    with tempfile.TemporaryDirectory() as out:
        one("plain", 0.1, out)  # warm: imports, certificate cache
        for _ in range(args.repeat):
            for k in kinds:  # alternated
                c, got = one(k, args.duration, out)
                cpu[k].append(c)
                if k == "client":
                    received.append(got)
    n = int(round(args.duration / 1e-3))
    base = statistics.median(cpu["plain"])
    print(f"cart_r2_robust, {args.duration:g} s at 1 ms ({n} samples), both logs, {args.repeat} alternated repeats")
    print(f"{'run':<36} {'CPU s median [range]':>26} {'x plain':>8} {'us/sample over plain':>22}")
    for k, label in zip(kinds, ("plain", "--foxglove, no client", "--foxglove, one client subscribed")):
        m = statistics.median(cpu[k])
        print(f"{label:<36} {m:>10.3f} [{min(cpu[k]):.3f}, {max(cpu[k]):.3f}] {m / base:>8.2f} "
              f"{1e6 * (m - base) / n:>22.2f}")
    print(f"messages the client received per run: {received} (loop samples: {n}, plus /tf at 60 Hz and the one-offs)")


if __name__ == "__main__":
    main()
