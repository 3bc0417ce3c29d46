"""Reading an MCAP run log back into arrays (replay, check, verify, report): checked, bounded, tolerant of truncation.

A log is input like any other, possibly from elsewhere, so the file is parsed here record by record
(the MCAP layout: magic, records of opcode + u64 length, footer, magic) with every declared length
checked against the bytes that exist before anything is read or allocated, and every chunk
decompressed to at most its declared size (itself bounded: :data:`MAX_CHUNK_BYTES`, and
:data:`MAX_EXPANSION` times the file's size in all).

Three outcomes:

- **complete**: the file ends with its footer; the CRC-32s the writer stored are checked: each
  chunk's data, the data section (DataEnd) and the summary (Footer), and the message counts of the
  summary's statistics against what was read. A failed chunk CRC (or any broken structure) is
  **damage**: :class:`DamagedLog`, one line naming the chunk or byte offset and how many samples
  before it are intact; no sample after the damage is returned. A data-section CRC that fails while
  every chunk's own CRC holds and every message is accounted for means the flip lies outside the
  samples (an index, the metadata): the samples are returned with :attr:`LogData.warning` saying so.
- **truncated** (a run killed mid-way: no footer, the last record cut): everything up to the last
  complete chunk is kept (the sink ends a chunk at every flush) and the warning says how much.
- not a log: :class:`~ftstab_mj.config.errors.LogError`.

Both encodings of ``/loop/<name>`` are read: protobuf ``ftstab.LoopSample`` (logs/encoding.py, the
current one) and JSON (logs written by ftstab_mj 0.1); ``/tf`` as protobuf or JSON likewise.
Chunks written without a CRC (0.1) cannot be checked: :attr:`LogData.crc_checked` says so.
"""

from __future__ import annotations

import json
import struct
import zlib
from dataclasses import dataclass, field, replace

import numpy as np

from ftstab_mj.config.errors import LogError
from ftstab_mj.simulation.records import LOOP_FIELDS, RunInfo

MCAP_MAGIC = b"\x89MCAP0\r\n"
from ftstab_mj.config.limits import MAX_CHUNK_BYTES, MAX_LOG_BYTES, MAX_RECORD_BYTES  # noqa: E402
MAX_EXPANSION = 64  # all chunks together decompress to at most this times the file size (+ 64 MiB)
MAX_LOOPS = 64
MAX_BODIES = 10_000

_OP = {0x01: "header", 0x02: "footer", 0x03: "schema", 0x04: "channel", 0x05: "message", 0x06: "chunk",
       0x07: "message index", 0x08: "chunk index", 0x09: "attachment", 0x0A: "attachment index",
       0x0B: "statistics", 0x0C: "metadata", 0x0D: "metadata index", 0x0E: "summary offset", 0x0F: "data end"}
_DATA_SECTION = {0x01, 0x06, 0x07, 0x0C, 0x0F}  # what an ftstab log holds outside its summary
_SUMMARY = {0x03, 0x04, 0x08, 0x0A, 0x0B, 0x0D, 0x0E, 0x02}
_IN_CHUNK = {0x03, 0x04, 0x05}


class DamagedLog(LogError):
    """A log whose bytes were altered (a failed CRC, a broken record): where, and what is intact before it."""


@dataclass
class LogData:
    """A run as read from its log.

    loops: {loop name: {field: array}} (z (n, r), others (n,); every field the log holds, at least
    records.LOOP_FIELDS), non-finite values as NaN;
    pose_t (m,), pose_pos (m, nbody, 3), pose_quat (m, nbody, 4) (w, x, y, z): the body poses
    of /tf, at their own (display) rate; recorded: the /metrics message ({"status", "message",
    "metrics"}) or None when the run did not finish; complete: the file ends with its footer;
    bytes_read / bytes_total: how much of the file was usable; encoding: "protobuf" | "json" (the
    loop channels); crc_checked: every chunk carried a CRC and it held; notes: other findings
    (e.g. damage outside the samples), each one line. A log read as it streams (:class:`LogStream`)
    holds no sample: loops {name: {}}, no poses (unless asked), counts {loop name: samples} and
    t_last (s, the last sample's time) instead.
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
    encoding: str = "protobuf"
    crc_checked: bool = True
    notes: tuple = ()
    counts: dict | None = None  # {loop name: samples} of a log read as it streams (LogStream: no samples kept)
    t_last: float | None = None  # and the time of its last sample (s)

    @property
    def n_samples(self) -> int:
        if self.counts is not None:
            return min(self.counts.values(), default=0)
        return min((len(a["t"]) for a in self.loops.values()), default=0)

    @property
    def warning(self) -> str | None:
        """One line saying what is wrong with a log that could still be read (None for an intact log)."""
        if self.complete:
            return " ".join(self.notes) or None
        t_last = self.t_last if self.counts is not None else max(
            (float(a["t"][-1]) for a in self.loops.values() if len(a["t"])), default=None)
        upto = f"up to t = {t_last:.6g} s" if t_last is not None else "no sample"
        return (f"{self.path}: truncated log (the run did not finish writing it): recovered {self.n_samples} "
                f"samples per loop, {upto}, from the first {self.bytes_read} of {self.bytes_total} bytes "
                "(the last complete chunk); later samples are lost")


class _Damage(Exception):
    """Internal: where (byte offset) and what is broken."""

    def __init__(self, offset: int, what: str, cut: bool = False):
        self.offset, self.what, self.cut = offset, what, cut  # cut: a top-level record runs past the file's end
        self.in_chunk = False  # offset in a chunk's decompressed records, not in the file


def _u(fmt: str, buf, pos: int, end: int, what: str):
    size = struct.calcsize(fmt)
    if pos + size > end:
        raise _Damage(pos, f"{what} runs past the end of its record")
    return struct.unpack_from(fmt, buf, pos), pos + size


def _string(buf, pos: int, end: int, what: str) -> tuple[str, int]:
    (n,), pos = _u("<I", buf, pos, end, what)
    if pos + n > end:
        raise _Damage(pos, f"{what} declares {n} bytes, more than its record holds")
    try:
        return bytes(buf[pos:pos + n]).decode("utf-8"), pos + n
    except UnicodeDecodeError:
        raise _Damage(pos, f"{what} is not UTF-8") from None


def _bytes(buf, pos: int, end: int, what: str, prefix: str = "<I") -> tuple[bytes, int]:
    (n,), pos = _u(prefix, buf, pos, end, what)
    if pos + n > end:
        raise _Damage(pos, f"{what} declares {n} bytes, more than its record holds")
    return bytes(buf[pos:pos + n]), pos + n


def _records(buf, pos: int, end: int, where: str):
    """Yield (opcode, body start, body end, record start) of the records in buf[pos:end]; every
    declared length is checked against ``end`` first. A record past ``end`` raises _Damage with
    cut = top (a truncation when it happens at the top level of a file that never got its footer)."""
    top = where == "in the file"
    while pos < end:
        if pos + 9 > end:
            raise _Damage(pos, f"a record header {where} is cut short", cut=top)
        op, length = struct.unpack_from("<BQ", buf, pos)
        if length > end - pos - 9:
            raise _Damage(pos, f"the {_OP.get(op, f'0x{op:02x}')} record {where} declares {length} bytes, "
                               f"past the end ({end - pos - 9} left)", cut=top)
        yield op, pos + 9, pos + 9 + length, pos
        pos += 9 + length


class _Parser:
    """Collects schemas, channels, metadata and the message counts while walking the file; the
    messages themselves are handed over chunk by chunk (:meth:`walk`)."""

    def __init__(self, buf, path: str, release=None):
        """buf: the whole file (a mapped file), or None for one read as it streams (:class:`_Stream`:
        ``total`` then counts the bytes read so far)."""
        self.buf, self.path, self.total = buf, path, len(buf) if buf is not None else len(MCAP_MAGIC)
        self.release = release  # release(offset): the file's bytes before offset are not read again
        self.schemas: dict[int, tuple] = {}  # id -> (name, encoding, data)
        self.channels: dict[int, tuple] = {}  # id -> (topic, schema id, message encoding)
        self.counts: dict[int, int] = {}  # channel id -> messages so far (their sequence numbers: 0, 1, ...)
        self.last_time: dict[int, int] = {}  # channel id -> log time (ns) of its last message
        self.crc = zlib.crc32(MCAP_MAGIC)  # of the data section read so far (the caller checked the magic)
        self.versions: dict = {}
        self.chunks = 0
        self.crc_checked = True
        self.expanded = 0
        self.good = 0  # end offset of the last complete, intact record
        self.complete = False
        self.data_end = None  # (record start, stored data-section CRC)
        self.stats = None  # (message count, chunk count, {channel: count}) from the summary
        self.footer = None  # (summary start, summary CRC, footer record start)
        self.summary = None  # (offset of the first record after DataEnd, CRC of the records from it to the footer)
        self.footer_head = b""  # the footer record's bytes its CRC covers (opcode, length, two offsets)

    # -- inside a chunk ---------------------------------------------------------------------------
    def _inner(self, buf, pos, end, chunk: int):
        staged = ([], [], [])
        for op, b0, b1, _ in _records(buf, pos, end, f"inside chunk {chunk}"):
            if op not in _IN_CHUNK:
                raise _Damage(b0, f"chunk {chunk} holds a {_OP.get(op, f'0x{op:02x}')} record")
            if op == 0x03:
                (sid,), p = _u("<H", buf, b0, b1, "schema id")
                name, p = _string(buf, p, b1, "schema name")
                enc, p = _string(buf, p, b1, "schema encoding")
                data, p = _bytes(buf, p, b1, "schema data")
                staged[0].append((sid, (name, enc, data)))
            elif op == 0x04:
                (cid, sid), p = _u("<HH", buf, b0, b1, "channel ids")
                topic, p = _string(buf, p, b1, "channel topic")
                enc, p = _string(buf, p, b1, "message encoding")
                staged[1].append((cid, (topic, sid, enc)))
            else:
                (cid, seq, t_log, _t_pub), p = _u("<HIQQ", buf, b0, b1, "message header")
                staged[2].append((cid, (seq, t_log, bytes(buf[p:b1]))))
        return staged

    def _chunk(self, buf, b0: int, b1: int):
        k = self.chunks + 1  # chunks are counted from 1 in messages
        (_t0, _t1, size, crc), p = _u("<QQQI", buf, b0, b1, f"chunk {k} header")
        comp, p = _string(buf, p, b1, f"chunk {k} compression")
        (n,), p = _u("<Q", buf, p, b1, f"chunk {k} records length")
        if n != b1 - p:
            raise _Damage(p, f"chunk {k} declares {n} bytes of records, its record holds {b1 - p}")
        if comp not in ("", "zstd", "lz4"):
            raise _Damage(b0, f"chunk {k} declares an unknown compression {comp[:20]!r}")
        if size > MAX_CHUNK_BYTES or self.expanded + size > MAX_EXPANSION * self.total + (64 << 20):
            raise _Damage(b0, f"chunk {k} declares {size} uncompressed bytes, beyond what a log of "
                              f"{self.total} bytes can hold")
        data = bytes(buf[p:b1])
        try:
            if comp == "zstd":
                import zstandard

                raw = zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
            elif comp == "lz4":
                import lz4.frame

                raw = lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=size)
            else:
                raw = data
        except Exception:
            raise _Damage(b0, f"chunk {k} does not decompress ({comp})") from None
        if len(raw) != size:
            raise _Damage(b0, f"chunk {k} decompresses to {len(raw)} bytes, it declares {size}")
        if crc == 0:
            self.crc_checked = False  # written without a CRC (ftstab_mj 0.1): nothing to check
        elif zlib.crc32(raw) != crc:
            raise _Damage(b0, f"chunk {k} fails its CRC check")
        self.expanded += size
        try:
            return self._inner(raw, 0, len(raw), k)
        except _Damage as d:
            d.in_chunk = True
            raise

    def _commit(self, staged):
        """A chunk found intact: its schemas and channels are known from now on; its messages
        [(channel id, (sequence, log time, data))] are checked to continue their channel's sequence."""
        schemas, channels, messages = staged
        self.schemas.update(schemas)
        self.channels.update(channels)
        for cid, (seq, t_log, _) in messages:
            if seq != self.counts.get(cid, 0):
                topic = self.channels.get(cid, ("?", 0, ""))[0]
                raise DamagedLog(f"{self.path}: damaged log: {topic} messages are missing or out of order "
                                 "(their sequence numbers have gaps)")
            self.counts[cid] = seq + 1
            self.last_time[cid] = t_log
        return messages

    # -- the file ---------------------------------------------------------------------------------
    def _file_records(self):
        """(opcode, buffer, body start, body end, record start) of the mapped file's top-level records."""
        for op, b0, b1, start in _records(self.buf, len(MCAP_MAGIC), self.total, "in the file"):
            yield op, self.buf, b0, b1, start

    def walk(self, stream=None):
        """Walk every record (of the mapped file, or of ``stream``: a :class:`_Stream`), yielding the
        messages of each intact chunk in turn ([(channel id, (sequence, log time, data))]). Raises
        _Damage at the first broken record; a cut at the end of a file that never got its footer is a
        truncation (stops quietly, complete False)."""
        if stream is None:
            buf, total = self.buf, self.total
            ended = bool(buf[-len(MCAP_MAGIC):] == MCAP_MAGIC and total >= 2 * len(MCAP_MAGIC))
            records = self._file_records()
        else:
            records = stream.records(self)
        try:
            for op, buf, b0, b1, start in records:
                try:
                    messages = self._record(op, buf, b0, b1, start)
                except _Damage as d:  # a stream's record is a buffer of its own: the offset in the file
                    if stream is not None and not d.in_chunk:
                        d.offset += start - (b0 - 9)
                    raise
                if messages is not None:
                    yield messages
                if self.complete:
                    if stream is not None:
                        stream.finish(self)
                    self.good = self.total
                    return
        except _Damage as d:
            if d.cut and not (ended if stream is None else stream.ended):  # a run killed mid-way: keep what was flushed
                return
            raise

    def _record(self, op: int, buf, b0: int, b1: int, start: int):
        """Read one top-level record (its body buf[b0:b1], starting at byte ``start`` of the file): the
        messages of a chunk, else None; the footer sets :attr:`complete`."""
        in_summary = self.data_end is not None
        allowed = _SUMMARY if in_summary else _DATA_SECTION
        if op not in allowed:
            raise _Damage(b0 - 9, f"unexpected {_OP.get(op, f'0x{op:02x}')} record "
                                  f"{'in the summary' if in_summary else 'in the data section'}")
        whole = buf[b0 - 9:b1]  # the record with its opcode and length
        if not in_summary and op != 0x0F:  # the data section's CRC covers what precedes DataEnd
            self.crc = zlib.crc32(whole, self.crc)
        elif in_summary and op != 0x02:  # the summary's CRC: its records, then the footer's head
            self.summary = (self.summary[0], zlib.crc32(whole, self.summary[1]))
        end = start + 9 + (b1 - b0)  # where the record ends in the file
        if op == 0x06:
            messages = self._commit(self._chunk(buf, b0, b1))
            self.chunks += 1
            self.good = end
            if self.release is not None:
                self.release(end)
            return messages
        if op == 0x0C:
            name, p = _string(buf, b0, b1, "metadata name")
            (n,), p = _u("<I", buf, p, b1, "metadata map length")
            q, entries = p, {}
            while q < p + n:
                key, q = _string(buf, q, b1, "metadata key")
                value, q = _string(buf, q, b1, "metadata value")
                entries[key] = value
            if name == "versions":
                self.versions = entries
        elif op == 0x0F:
            (crc,), _ = _u("<I", buf, b0, b1, "data end")
            self.data_end = (start, crc)
            self.summary = (end, 0)
        elif op == 0x0B:
            (count, _s, _c, _a, _m, chunks, _t0, _t1), p = _u("<QHIIIIQQ", buf, b0, b1, "statistics")
            (n,), p = _u("<I", buf, p, b1, "statistics channel counts")
            if n != b1 - p or n % 10:
                raise _Damage(p, "the statistics' channel counts do not fill their record")
            per = {cid: c for cid, c in struct.iter_unpack("<HQ", bytes(buf[p:b1]))}
            self.stats = (count, chunks, per)
        elif op == 0x02:
            (s_start, _off, s_crc), _ = _u("<QQI", buf, b0, b1, "footer")
            self.footer = (s_start, s_crc, start)
            self.footer_head = bytes(buf[b0 - 9:b0 + 16])
            self.complete = True
        if not in_summary:
            self.good = end
        return None

    def check_integrity(self) -> list[str]:
        """For a complete file: the stored CRCs and counts. Raises _Damage when samples may be
        affected; returns notes for damage outside them."""
        notes = []
        summary_ok = False
        if self.footer is not None:
            s_start, s_crc, f_start = self.footer
            if s_crc and 0 < s_start <= f_start:
                if self.buf is not None:
                    got = zlib.crc32(bytes(self.buf[f_start:f_start + 9 + 16]), zlib.crc32(bytes(self.buf[s_start:f_start])))
                else:  # read as it streamed: the CRC of the records after DataEnd, where the summary starts
                    got = zlib.crc32(self.footer_head, self.summary[1]) if s_start == self.summary[0] else None
                summary_ok = got == s_crc
                if not summary_ok:
                    notes.append(f"{self.path}: the summary fails its CRC check (not used).")
        if summary_ok and self.stats is not None:
            count, chunks, per = self.stats
            have = self.counts
            if chunks != self.chunks or count != sum(have.values()) or any(
                    per.get(cid, 0) != n for cid, n in have.items()):
                raise _Damage(0, f"the summary counts {chunks} chunks and {count} messages, the file holds "
                                 f"{self.chunks} chunks and {sum(have.values())} messages (a record was skipped)")
        if self.data_end is not None and self.data_end[1]:
            start, crc = self.data_end
            if self.crc != crc:
                if not (self.crc_checked and summary_ok):
                    raise _Damage(0, "the data section fails its CRC check")
                notes.append(f"{self.path}: the data section fails its CRC check outside the chunks (an index or "
                             "the metadata was altered); every chunk's own CRC holds, so the samples are intact.")
        return notes


def _rows(datas: list[bytes], what: str) -> list:
    """Decode many JSON messages at once (one json.loads over a JSON array of them)."""
    try:
        return json.loads(b"[" + b",".join(datas) + b"]") if datas else []
    except (ValueError, RecursionError):
        raise LogError(f"{what}: expected JSON messages, found bytes that do not parse") from None


def _json_loop(rows: list, r: int, what: str) -> dict:
    try:
        out = {f: np.array([row[f] for row in rows], dtype=float) for f in LOOP_FIELDS if f != "z"}
        out["z"] = np.array([row["z"] for row in rows], dtype=float).reshape(len(rows), r)
    except (KeyError, TypeError, ValueError):
        raise LogError(f"{what}: expected JSON samples with the fields {', '.join(LOOP_FIELDS)}") from None
    return out


def _protobuf_loop(schema: tuple, datas: list[bytes], r: int, what: str) -> dict:
    from ftstab_mj.logs.encoding import decode_each, layout_from_schema

    name, encoding, data = schema
    if encoding != "protobuf":
        raise LogError(f"{what}: expected a protobuf schema, found {encoding!r}")
    try:
        layout, cls = layout_from_schema(data, what, datas[0] if datas else None)
        out = layout.decode(b"".join(datas), len(datas))
        if out is None:
            out = decode_each(layout, cls, datas, what)
    except ValueError as exc:
        raise LogError(str(exc)) from None
    except Exception:  # a message the protobuf runtime refuses
        raise LogError(f"{what}: the messages do not decode as {name}") from None
    if datas:
        missing = [f for f in LOOP_FIELDS if f not in out]
        if missing or out["z"].ndim != 2 or out["z"].shape[1] != r:
            raise LogError(f"{what}: expected the fields {', '.join(LOOP_FIELDS)} with z of {r} values, found "
                           f"{', '.join(out) or 'none'}")
    else:
        out = {f: np.empty((0, r)) if f == "z" else np.empty(0) for f in LOOP_FIELDS}
    return out


class LogStream:
    """A log read as it streams, chunk by chunk, in memory that does not grow with it (what replay and
    check need: the samples pass through once). The same reading and checks as :func:`read_log`::

        stream = LogStream(path)
        for loops in stream.batches():   # {loop name: {field: array}} of one chunk (every loop; some empty)
            ...                           # stream.info (RunInfo) is known from the first batch on
        log = stream.log                  # LogData once read: no samples in loops (n_samples counts them), no poses

    The file is mapped and the pages of each chunk given back once it is read. ``poses``: also keep
    the /tf messages (then ``log`` has the poses); "chunks": hand them over chunk by chunk instead, as
    ``chunk_poses`` (t (k,), pos (k, nbody, 3), quat (k, nbody, 4)) beside each batch. Raises as
    read_log does, LogError or DamagedLog, at the point of the file where the problem is found.
    """

    KEPT = ("/scenario", "/run_info", "/metrics")  # small topics kept whole (JSON)

    def __init__(self, path, poses: bool | str = False):
        self.path, self.poses = str(path), poses
        self.chunk_poses = None
        self.info: RunInfo | None = None
        self.log: LogData | None = None
        self._n = {}  # loop name -> samples read
        self._t_last = None  # time of the last sample read (s)
        self._layouts = {}  # channel id -> protobuf layout (decoded once)

    def batches(self):
        path = self.path
        with _mapped(path) as (buf, release, source):
            if source is None and bytes(buf[:len(MCAP_MAGIC)]) != MCAP_MAGIC:
                raise LogError(f"{path}: not an MCAP log (expected a file starting with the MCAP magic bytes, "
                               f"found {bytes(buf[:8])!r})")
            p = _Parser(buf, path, release)
            kept = {}  # topic -> [data]
            pending = []  # loop messages met before /run_info (not in a log ftstab wrote)
            notes = []
            try:
                for messages in p.walk(source):
                    loops = {}
                    for cid, (_seq, _t, data) in messages:
                        topic = p.channels.get(cid, ("?", 0, ""))[0]
                        if topic.startswith("/loop/"):
                            loops.setdefault(cid, []).append(data)
                        elif topic in self.KEPT or (self.poses and topic == "/tf"):
                            kept.setdefault(topic, []).append(data)
                    if self.info is None and "/run_info" in kept:
                        self.info, notes = self._info(kept)
                    if self.poses == "chunks" and kept.get("/tf"):
                        loops[None] = kept.pop("/tf")  # (the chunk's poses travel with its samples)
                    if loops:
                        pending.append(loops)
                    if self.info is not None:
                        for chunk in pending:
                            yield self._decode(p, chunk)
                        pending = []
                if p.complete:
                    notes += p.check_integrity()
            except _Damage as d:
                raise DamagedLog(_damage_line(path, p, d)) from None
            topics = {p.channels.get(cid, ("?",))[0] for cid in p.counts}
            if "/run_info" not in topics:
                raise LogError(f"{path}: not an ftstab run log (expected a /run_info message at its start, "
                               f"found topics {sorted(topics) or 'none'})")
            info = self.info
            encoding = "protobuf"
            for cid in p.counts:
                topic, _, enc = p.channels[cid]
                if topic.startswith("/loop/") and enc == "json":
                    encoding = "json"
            for lp in info.loops:
                self._n.setdefault(lp.name, 0)
            tf_cid = [cid for cid in p.counts if p.channels[cid][0] == "/tf"]
            tf_enc = p.channels[tf_cid[0]][2] if tf_cid else "protobuf"
            pose_t, pos, quat = _poses(kept.get("/tf", []), tf_enc, info.body_names, f"{path} /tf")
            metrics = _rows(kept.get("/metrics", []), f"{path} /metrics")
            recorded = metrics[-1] if metrics else None
            if recorded is not None and not (isinstance(recorded, dict) and isinstance(recorded.get("status"), str)):
                raise LogError(f"{path} /metrics: expected an object with a status, found {str(recorded)[:60]!r}")
            self.log = LogData(path=path, info=info, loops={name: {} for name in self._n}, pose_t=pose_t,
                               pose_pos=pos, pose_quat=quat, recorded=recorded, versions=p.versions,
                               complete=p.complete, bytes_read=p.total if p.complete else p.good,
                               bytes_total=p.total, encoding=encoding, crc_checked=p.crc_checked,
                               notes=tuple(notes), counts=dict(self._n), t_last=self._t_last)

    def _info(self, kept):
        """RunInfo from the /scenario and /run_info messages, and the notes on its model."""
        path, notes = self.path, []
        scenario = _rows(kept.get("/scenario", []), f"{path} /scenario")
        run = _rows(kept["/run_info"], f"{path} /run_info")[0]
        info = _run_info(path, scenario[0] if scenario else {}, run)
        if info.model_xml is not None:  # never compiled unless it is safe to (logs/scene.py)
            from ftstab_mj.logs.scene import check_untrusted_model

            try:
                check_untrusted_model(info.model_xml, f"{path} /run_info model_xml")
            except LogError as exc:
                notes.append(f"{exc}: the 3D model is left out.")
                info = replace(info, model_xml=None)
        return info, notes

    def _decode(self, p, chunk: dict) -> dict:
        """{loop name: {field: array}} of one chunk's loop messages ({channel id: [data]}); every loop."""
        by_name = {f"/loop/{lp.name}": lp for lp in self.info.loops}
        out = {lp.name: _empty_loop(lp.r) for lp in self.info.loops}
        if self.poses == "chunks":
            tf = [cid for cid in p.channels if p.channels[cid][0] == "/tf"]
            self.chunk_poses = _poses(chunk.pop(None, []), p.channels[tf[0]][2] if tf else "protobuf",
                                      self.info.body_names, f"{self.path} /tf")
        for cid, datas in chunk.items():
            topic, sid, enc = p.channels[cid]
            lp = by_name.get(topic)
            if lp is None:
                continue
            what = f"{self.path} {topic}"
            if enc == "json":
                out[lp.name] = _json_loop(_rows(datas, what), lp.r, what)
            elif sid in p.schemas:
                out[lp.name] = _protobuf_loop(p.schemas[sid], datas, lp.r, what)
            else:
                raise LogError(f"{what}: expected a schema for the channel, found none")
            t = out[lp.name]["t"]
            self._n[lp.name] = self._n.get(lp.name, 0) + len(t)
            if len(t):
                self._t_last = float(t[-1]) if self._t_last is None else max(self._t_last, float(t[-1]))
        return out


def _empty_loop(r: int) -> dict:
    return {f: np.empty((0, r)) if f == "z" else np.empty(0) for f in LOOP_FIELDS}


class _Stream:
    """The top-level records of a log read from a pipe, standard input or a device, one at a time, in
    memory bounded by the largest record accepted (:data:`MAX_CHUNK_BYTES` for a chunk,
    :data:`MAX_RECORD_BYTES` for any other), whatever the stream's length: its first bytes must be
    MCAP's magic (``/dev/zero`` is refused at its 8th byte) and every record's opcode and declared length
    are checked before its body is read (``/dev/urandom`` is refused at its first record)."""

    def __init__(self, f, path: str):
        self.f, self.path = f, path
        self.tail = b""  # the stream's last bytes read (whether a cut stream ended with the magic)
        self.ended = False  # the stream ended with MCAP's magic (a cut there is damage, not a truncation)
        head = self._read(len(MCAP_MAGIC))
        if head != MCAP_MAGIC:
            raise LogError(f"{path}: expected an MCAP log (its first bytes {MCAP_MAGIC!r}), found {head[:8]!r}")
        self.pos = len(head)

    def _read(self, n: int) -> bytes:
        """Up to n bytes (fewer at the end), read a MiB at a time so that memory follows what comes."""
        parts, got = [], 0
        while got < n:
            part = self.f.read(min(n - got, 1 << 20))
            if not part:
                break
            parts.append(part)
            got += len(part)
        data = b"".join(parts)
        self.tail = (self.tail + data[-len(MCAP_MAGIC):])[-len(MCAP_MAGIC):]
        if got < n:
            self.ended = self.tail == MCAP_MAGIC and self.pos + got >= 2 * len(MCAP_MAGIC)
        return data

    def records(self, parser: _Parser):
        """(opcode, buffer, body start, body end, record start) of each record, as _Parser.walk reads
        them; parser.total follows the bytes read."""
        while True:
            start = self.pos
            head = self._read(9)
            if not head:
                return  # the stream ends between two records, without a footer: a truncated log
            if len(head) < 9:
                raise _Damage(start, "a record header in the file is cut short", cut=True)
            op, length = struct.unpack("<BQ", head)
            if op not in _OP:
                raise _Damage(start, f"unknown record opcode 0x{op:02x} in the file")
            limit = MAX_CHUNK_BYTES + (1 << 20) if op == 0x06 else MAX_RECORD_BYTES  # a chunk: compressed + header
            if length > limit or start + 9 + length > MAX_LOG_BYTES:
                raise _Damage(start, f"the {_OP[op]} record in the file declares {length} bytes, more than a log "
                                     f"read as it streams accepts ({limit})")
            body = self._read(length)
            self.pos = parser.total = start + 9 + len(body)
            if len(body) < length:
                raise _Damage(start, f"the {_OP[op]} record in the file declares {length} bytes, past the end "
                                     f"({len(body)} left)", cut=True)
            yield op, head + body, 9, 9 + length, start

    def finish(self, parser: _Parser) -> None:
        """After the footer: its closing magic (parser.total counts it; what may follow is not read)."""
        parser.total = self.pos + len(self._read(len(MCAP_MAGIC)))


class _mapped:
    """``with _mapped(path) as (buf, release, stream)``: the file's bytes as a memoryview of a read-only
    map, release(offset) giving the pages before offset back (MADV_DONTNEED: read again from the page
    cache if touched), so a long log read front to back does not stay resident; stream None. A file that
    cannot be mapped (a pipe, standard input as ``-`` or ``/dev/stdin``, a FIFO, a device, an empty
    file): buf and release None, stream a :class:`_Stream` of it (its magic checked)."""

    def __init__(self, path: str):
        self.path = path

    def __enter__(self):
        import mmap

        import os
        import stat

        try:
            f = open(0 if self.path == "-" else self.path, "rb", closefd=self.path != "-")  # -: standard input
            st = os.fstat(f.fileno())
        except OSError as exc:
            raise LogError(f"{self.path}: cannot read the log ({exc.strerror})") from None
        self.file, self.map, self.released = f, None, 0
        if stat.S_ISDIR(st.st_mode):
            f.close()
            raise LogError(f"{self.path}: expected an MCAP log file, found a directory")
        if stat.S_ISREG(st.st_mode) and st.st_size > MAX_LOG_BYTES:
            f.close()
            raise LogError(f"{self.path}: expected a log of at most {MAX_LOG_BYTES} bytes (a limit), "
                           f"found {st.st_size} bytes")
        try:
            if not stat.S_ISREG(st.st_mode):  # a pipe, a device (/dev/zero): no map, read below
                raise ValueError
            self.map = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        except (OSError, ValueError):
            try:
                return None, None, _Stream(f, self.path)
            except OSError as exc:
                f.close()
                raise LogError(f"{self.path}: cannot read the log ({exc.strerror})") from None
            except LogError:
                f.close()
                raise
        self.view = memoryview(self.map)
        return self.view, self._release if hasattr(mmap, "MADV_DONTNEED") else None, None

    def _release(self, offset: int) -> None:
        import mmap

        end = offset - offset % mmap.PAGESIZE
        if end > self.released:
            try:
                self.map.madvise(mmap.MADV_DONTNEED, self.released, end - self.released)
            except OSError:
                return
            self.released = end

    def __exit__(self, *exc):
        if self.map is not None:
            self.view.release()
            try:
                self.map.close()
            except BufferError:  # a view of it is still referenced (an exception's frame): let GC close it
                pass
        self.file.close()
        return False


def read_log(path) -> LogData:
    """Read an ftstab MCAP log (complete or truncated) whole: every sample and pose. Raises LogError
    when it is not one and DamagedLog when its bytes were altered. (:class:`LogStream` reads it in
    bounded memory.)"""
    stream = LogStream(path, poses=True)
    parts = {}
    for loops in stream.batches():
        for name, arrays in loops.items():
            if len(arrays["t"]):
                parts.setdefault(name, []).append(arrays)
    log = stream.log
    loops = {}
    for lp in log.info.loops:
        got = parts.get(lp.name)
        loops[lp.name] = ({f: np.concatenate([a[f] for a in got]) for f in got[0]} if got else _empty_loop(lp.r))
    return replace(log, loops=loops, counts=None, t_last=None)


def stream_metrics(path, progress=None):
    """(log, metrics) of the log at ``path`` read as it streams, in memory that does not grow with it:
    its chunks feed ftstab_mj.metrics.run_metrics.MetricsStream as a run's batches do (the same bits as
    compute_metrics of its arrays), with the recorded status (interrupted when none). The log
    (LogData) keeps no samples. progress(text): a status line while a loop's certificate is
    computed (metrics.run_certificates: a log from another machine misses the cache). Raises
    LogError, DamagedLog."""
    from ftstab_mj.metrics.run_metrics import MetricsStream, run_certificates
    from ftstab_mj.simulation.records import INTERRUPTED

    reading, stream = LogStream(path), None
    try:
        for loops in reading.batches():
            if stream is None:
                run_certificates(reading.info, progress)
                stream = MetricsStream(reading.info)
            stream.update(loops)
        log = reading.log
        status = log.recorded["status"] if log.recorded else INTERRUPTED
        return log, (stream or MetricsStream(log.info)).result(status)
    except ValueError as exc:  # samples whose times are not spaced by the period (not written by a run)
        if isinstance(exc, LogError):
            raise
        raise LogError(f"{path}: {exc}") from None


def _damage_line(path: str, p: _Parser, d: _Damage) -> str:
    """One line: where the damage is and how much before it is intact."""
    counts = []
    for cid, n in p.counts.items():
        topic = p.channels.get(cid, ("?",))[0]
        if topic.startswith("/loop/") and n:
            counts.append(f"{n} samples of {topic} (up to t = {p.last_time[cid] * 1e-9:.6g} s)")
    before = "; ".join(counts) or "no sample"
    return (f"{path}: damaged log: {d.what} (byte {d.offset}); intact before it: {before}; nothing after it is "
            "used")


def _run_info(path: str, scenario, run) -> RunInfo:
    """RunInfo from a log's /run_info, with its sizes bounded (a log may come from anywhere)."""
    what = f"{path} /run_info"
    if not isinstance(run, dict) or not isinstance(scenario, dict):
        raise LogError(f"{what}: expected JSON objects, found {type(run).__name__}")
    loops, bodies = run.get("loops"), run.get("body_names", ())
    if not isinstance(loops, list) or not 1 <= len(loops) <= MAX_LOOPS:
        raise LogError(f"{what}: loops: expected a list of 1 to {MAX_LOOPS} loops, found {str(loops)[:60]}")
    if not isinstance(bodies, list | tuple) or len(bodies) > MAX_BODIES or not all(isinstance(b, str) for b in bodies):
        raise LogError(f"{what}: body_names: expected at most {MAX_BODIES} names")
    for lp in loops:
        r = lp.get("r") if isinstance(lp, dict) else None
        if isinstance(r, bool) or not isinstance(r, int) or not 1 <= r <= 64:
            raise LogError(f"{what}: loops.r: expected an integer from 1 to 64, found {str(r)[:40]}")
    try:
        info = RunInfo.from_dict({"scenario": scenario, **run})
    except Exception:
        raise LogError(f"{what}: expected the fields of RunInfo (loops, period, physics_step, ...), found "
                       f"keys {sorted(run)[:12]}") from None
    if not (np.isfinite(info.period) and info.period > 0):
        raise LogError(f"{what}: period: expected a finite number > 0, found {info.period!r}")
    if not isinstance(info.model_xml, str | None):
        raise LogError(f"{what}: model_xml: expected a string or null")
    if info.kernel not in ("", "native", "python"):  # "": a log written before the path was recorded
        raise LogError(f"{what}: kernel: expected \"native\" or \"python\", found {info.kernel[:40]!r}")
    return info


def _poses(datas: list[bytes], encoding: str, body_names, what: str):
    """(t (m,), pos (m, nbody, 3), quat (m, nbody, 4) (w, x, y, z)) of the /tf messages."""
    nb = len(body_names)
    index = {b: i for i, b in enumerate(body_names)}
    t = np.empty(len(datas))
    pos = np.zeros((len(datas), nb, 3))
    quat = np.zeros((len(datas), nb, 4))
    if not datas:
        return t, pos, quat
    try:
        if encoding == "json":
            for k, row in enumerate(_rows(datas, what)):
                for tf in row["transforms"]:
                    i = index[tf["child_frame_id"]]
                    s, p, q = tf["timestamp"], tf["translation"], tf["rotation"]
                    t[k] = s["sec"] + s["nsec"] * 1e-9
                    pos[k, i] = (p["x"], p["y"], p["z"])
                    quat[k, i] = (q["w"], q["x"], q["y"], q["z"])
        else:
            cls = _frame_transforms_class()
            for k, data in enumerate(datas):
                for tf in cls.FromString(data).transforms:
                    i = index[tf.child_frame_id]
                    p, q = tf.translation, tf.rotation
                    t[k] = tf.timestamp.seconds + tf.timestamp.nanos * 1e-9
                    pos[k, i] = (p.x, p.y, p.z)
                    quat[k, i] = (q.w, q.x, q.y, q.z)
    except LogError:
        raise
    except Exception:
        raise LogError(f"{what}: expected foxglove.FrameTransforms of the logged bodies") from None
    return t, pos, quat


def _frame_transforms_class():
    """The protobuf class of the official foxglove.FrameTransforms (from foxglove-sdk's schema, not the log's)."""
    from foxglove.messages import FrameTransforms
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    pool = descriptor_pool.DescriptorPool()
    for f in descriptor_pb2.FileDescriptorSet.FromString(FrameTransforms.get_schema().data).file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName("foxglove.FrameTransforms"))
