"""Reading an MCAP run log back into arrays (replay, check, verify), tolerating truncation.

The file is read sequentially, record by record. A run killed mid-way (SIGKILL, power loss)
leaves no summary and usually a partial last record: everything up to the last complete
chunk is kept (the sink ends a chunk at every flush), and :attr:`LogData.warning` says how much
was recovered. A file that does not start with the MCAP magic, or that lacks the /run_info
written at the start of every ftstab log, raises :class:`~ftstab_mj.errors.LogError`.
"""

from __future__ import annotations

import json
import struct
import zlib
from dataclasses import dataclass, field

import numpy as np

from ftstab_mj.errors import LogError
from ftstab_mj.records import LOOP_FIELDS, RunInfo

MCAP_MAGIC = b"\x89MCAP0\r\n"


@dataclass
class LogData:
    """A run as read from its log.

    loops: {loop name: {field: array}} (z (n, r), others (n,)), non-finite values as NaN;
    pose_t (m,), pose_pos (m, nbody, 3), pose_quat (m, nbody, 4) (w, x, y, z): the body poses
    of /tf, at their own (display) rate; recorded: the /metrics message ({"status", "message",
    "metrics"}) or None when the run did not finish; complete: the file ends with its footer;
    bytes_read / bytes_total: how much of the file was usable.
    """

    path: str
    info: RunInfo
    loops: dict
    pose_t: np.ndarray
    pose_pos: np.ndarray
    pose_quat: np.ndarray
    recorded: dict | None
    versions: dict = field(default_factory=dict)
    complete: bool = True
    bytes_read: int = 0
    bytes_total: int = 0

    @property
    def n_samples(self) -> int:
        return min((len(a["t"]) for a in self.loops.values()), default=0)

    @property
    def warning(self) -> str | None:
        """One line saying how much of a truncated log was recovered (None for a complete log)."""
        if self.complete:
            return None
        t_last = max((float(a["t"][-1]) for a in self.loops.values() if len(a["t"])), default=None)
        upto = f"up to t = {t_last:.6g} s" if t_last is not None else "no sample"
        return (f"{self.path}: truncated log (the run did not finish writing it): recovered {self.n_samples} "
                f"samples per loop, {upto}, from the first {self.bytes_read} of {self.bytes_total} bytes "
                "(the last complete chunk); later samples are lost")


def _records(path: str, f):
    """Yield (record, end offset) of every complete top-level record; stops at the first damage.

    Returns (via StopIteration.value) True when the footer was reached.
    """
    from mcap.exceptions import McapError
    from mcap.records import Footer
    from mcap.stream_reader import StreamReader

    reader = StreamReader(f, emit_chunks=True)
    try:
        for rec in reader.records:
            yield rec, f.tell()
            if isinstance(rec, Footer):
                return True
    except (McapError, struct.error, EOFError, ValueError, MemoryError, zlib.error):
        return False
    return False


def _rows(datas: list[bytes]) -> list[dict]:
    """Decode many JSON messages at once (one json.loads over a JSON array of them)."""
    return json.loads(b"[" + b",".join(datas) + b"]") if datas else []


def _loop_arrays(rows: list[dict], r: int) -> dict:
    out = {f: np.array([row[f] for row in rows], dtype=float) for f in LOOP_FIELDS if f != "z"}
    out["z"] = np.array([row["z"] for row in rows], dtype=float).reshape(len(rows), r)
    return out


def read_log(path) -> LogData:
    """Read an ftstab MCAP log (complete or truncated). Raises LogError when it is not one."""
    from mcap.records import Channel, Chunk, Message, Metadata
    from mcap.stream_reader import breakup_chunk

    path = str(path)
    try:
        f = open(path, "rb")
    except OSError as exc:
        raise LogError(f"{path}: cannot read the log ({exc.strerror})") from None
    with f:
        head = f.read(len(MCAP_MAGIC))
        if head != MCAP_MAGIC:
            raise LogError(f"{path}: not an MCAP log (expected a file starting with the MCAP magic bytes, "
                           f"found {head[:8]!r})")
        f.seek(0, 2)
        total = f.tell()
        f.seek(0)
        channels: dict[int, str] = {}
        by_topic: dict[str, list[bytes]] = {}
        versions: dict = {}
        good = 0
        gen = _records(path, f)
        complete = False
        while True:
            try:
                rec, end = next(gen)
            except StopIteration as stop:
                complete = bool(stop.value)
                break
            inner = [rec]
            if isinstance(rec, Chunk):
                try:
                    inner = breakup_chunk(rec, validate_crc=True)
                except Exception:  # a damaged chunk (CRC, compression): stop at the last good one
                    break
            for r in inner:
                if isinstance(r, Channel):
                    channels[r.id] = r.topic
                elif isinstance(r, Message):
                    by_topic.setdefault(channels.get(r.channel_id, "?"), []).append(r.data)
                elif isinstance(r, Metadata) and r.name == "versions":
                    versions = dict(r.metadata)
            good = end
    if "/run_info" not in by_topic:
        raise LogError(f"{path}: not an ftstab run log (expected a /run_info message at its start, "
                       f"found topics {sorted(by_topic) or 'none'})")
    scenario = _rows(by_topic.get("/scenario", []))
    run = _rows(by_topic["/run_info"])[0]
    info = RunInfo.from_dict({"scenario": scenario[0] if scenario else {}, **run})
    loops = {lp.name: _loop_arrays(_rows(by_topic.get(f"/loop/{lp.name}", [])), lp.r) for lp in info.loops}
    pose_t, pos, quat = _poses(_rows(by_topic.get("/tf", [])), info.body_names)
    metrics = _rows(by_topic.get("/metrics", []))
    return LogData(path=path, info=info, loops=loops, pose_t=pose_t, pose_pos=pos, pose_quat=quat,
                   recorded=metrics[-1] if metrics else None, versions=versions,
                   complete=complete, bytes_read=good if not complete else total, bytes_total=total)


def _poses(rows: list[dict], body_names) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    nb = len(body_names)
    index = {b: i for i, b in enumerate(body_names)}
    t = np.empty(len(rows))
    pos = np.zeros((len(rows), nb, 3))
    quat = np.zeros((len(rows), nb, 4))
    for k, row in enumerate(rows):
        for tf in row["transforms"]:
            i = index[tf["child_frame_id"]]
            s = tf["timestamp"]
            t[k] = s["sec"] + s["nsec"] * 1e-9
            p, q = tf["translation"], tf["rotation"]
            pos[k, i] = (p["x"], p["y"], p["z"])
            quat[k, i] = (q["w"], q["x"], q["y"], q["z"])
    return t, pos, quat
