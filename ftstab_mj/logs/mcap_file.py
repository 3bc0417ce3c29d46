"""A chunked, indexed MCAP writer that adds many messages of a channel in one call.

``mcap.writer.Writer.add_message`` costs ~5 us a message in Python (a dataclass, statistics and an
index entry per message): more than a MuJoCo step. Here a batch of messages becomes one byte
string built with NumPy (record headers as a packed structured array, message-index offsets by
cumsum), so the per-message cost is a few list operations. The file layout is the one the mcap
Writer produces (magic, header, metadata, chunks each followed by its message indexes, data end,
summary with schemas, channels, statistics, chunk and metadata indexes, summary offsets, footer,
magic); the one-off records are serialized with the ``mcap`` package's own record classes.
The summary's chunk indexes (~110 bytes a chunk, one chunk a flush) are serialized as each chunk
is written and kept in an unlinked temporary file (:class:`_Spill`), not in memory: a writer holds
the same few kilobytes after 10 chunks as after 10^5.

Every :meth:`McapFile.flush` ends the current chunk and flushes the file: a reader that stops
at the first incomplete record gets everything flushed so far (logs/reader.py). After a write
error (a full disk), :meth:`McapFile.rollback` cuts the file back to the end of the last complete
flush and forgets what came after, so that the file can still be ended (a status, the summary).

CRC-32s are written as the format defines them: every chunk's uncompressed data, the whole data
section (in DataEnd) and the summary (in the Footer), so a reader tells a damaged file from an
intact one (logs/reader.py checks all three). They cost ~0.1 us a sample (zlib, ~1 GB/s).
"""

from __future__ import annotations

import os
import struct
import tempfile
import zlib

import numpy as np

MAGIC = b"\x89MCAP0\r\n"
_OP_MESSAGE = 0x05
_OP_MESSAGE_INDEX = 0x07
# Message record: opcode, record length, channel id, sequence, log time, publish time, then the data.
_MSG_HEADER = np.dtype([("op", "u1"), ("length", "<u8"), ("channel", "<u2"), ("sequence", "<u4"),
                        ("log_time", "<u8"), ("publish_time", "<u8")])
_MSG_FIXED = _MSG_HEADER.itemsize - 9  # record body bytes before the data (2 + 4 + 8 + 8)


class _Spill:
    """Bytes appended in order, kept in an unlinked temporary file (in memory when no temporary file
    can be made or written: a full disk), read back in blocks by :meth:`blocks`."""

    BLOCK = 1 << 20

    def __init__(self):
        self.size, self._mem, self._file = 0, bytearray(), None
        try:
            self._file = tempfile.TemporaryFile()
        except OSError:
            pass

    def append(self, data: bytes) -> None:
        if self._file is not None:
            try:
                if os.pwrite(self._file.fileno(), data, self.size) != len(data):  # a short write: the disk is full
                    raise OSError("short write")
                self.size += len(data)
                return
            except OSError:  # what the file holds (up to self.size) goes back to memory, and the rest stays there
                self._mem = bytearray(self._read())
                self._close()
        self._mem += data
        self.size += len(data)

    def truncate(self, size: int) -> None:
        """Forget the bytes from ``size`` on."""
        if self._file is not None:
            self._file.truncate(size)
        else:
            del self._mem[size:]
        self.size = size

    def _read(self):
        return b"".join(self.blocks())

    def blocks(self):
        """The bytes held, in blocks of at most BLOCK bytes."""
        if self._file is None:
            yield from (bytes(self._mem[i:i + self.BLOCK]) for i in range(0, self.size, self.BLOCK))
            return
        for i in range(0, self.size, self.BLOCK):
            yield os.pread(self._file.fileno(), min(self.BLOCK, self.size - i), i)

    def _close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    def close(self) -> None:
        self._close()
        self._mem, self.size = bytearray(), 0


class McapFile:
    """Write an MCAP file to the binary stream ``f`` (not closed by :meth:`finish`).

    compression: "zstd" | "lz4" | "" (none), per chunk. Times are integer nanoseconds.
    """

    def __init__(self, f, compression: str = "zstd"):
        from mcap.data_stream import RecordBuilder

        if compression not in ("zstd", "lz4", ""):
            raise ValueError(f"compression: expected zstd, lz4 or '', got {compression!r}")
        self._f = f
        self._compression = compression
        self._builder = RecordBuilder
        self._schemas, self._channels = [], []
        self._chunk_indexes = _Spill()  # the ChunkIndex records of the chunks written, serialized
        self._metadata_indexes = []
        self._parts: list[bytes] = []  # uncompressed records of the open chunk
        self._size = 0  # their total length
        self._index: dict[int, list[np.ndarray]] = {}  # channel -> [(n, 2) (log_time, offset)]
        self._t0 = self._t1 = None  # message time range of the open chunk
        self._counts: dict[int, int] = {}
        self._t_first = self._t_last = None
        self._n_chunks = 0
        self._data_crc = 0  # CRC-32 of every byte of the data section written so far
        self._written: dict[int, int] = {}  # channel -> messages in the chunks written
        self._mark()
        if compression == "zstd":  # level 1: ~2x faster than the default 3, files ~10% larger here
            import zstandard

            self._zstd = zstandard.ZstdCompressor(level=1)

    # -- the state after the last complete flush, which a write error returns to -----------------
    def _mark(self) -> None:
        self._flushed = (self._f.tell(), len(self._schemas), len(self._channels), self._chunk_indexes.size,
                         len(self._metadata_indexes), dict(self._counts), self._t_first, self._t_last,
                         self._n_chunks, self._data_crc, dict(self._written))

    def rollback(self) -> None:
        """After a write error: cut the file back to where the last complete :meth:`flush` left it
        and forget every record added since (a chunk, schemas and channels registered for it, the
        sequence numbers it used); writing can go on from there. Raises OSError when the file
        cannot be cut."""
        (end, n_schemas, n_channels, n_chunks, n_metadata, self._counts, self._t_first, self._t_last,
         self._n_chunks, self._data_crc, self._written) = self._flushed
        self._f.truncate(end)
        self._f.seek(end)
        del self._schemas[n_schemas:], self._channels[n_channels:], self._metadata_indexes[n_metadata:]
        self._chunk_indexes.truncate(n_chunks)
        self._counts, self._written = dict(self._counts), dict(self._written)
        self._parts, self._size, self._index, self._t0, self._t1 = [], 0, {}, None, None

    @property
    def ids(self) -> tuple[int, int]:
        """(schemas, channels) registered: the ids in use are 1..n of each."""
        return len(self._schemas), len(self._channels)

    # -- one-off records --------------------------------------------------------------------------
    def _write(self, data: bytes) -> None:
        """Write bytes of the data section (counted in its CRC)."""
        self._data_crc = zlib.crc32(data, self._data_crc)
        self._f.write(data)

    def _write_record(self, rec) -> None:
        """Serialize a record of mcap.records into the data section."""
        self._write(self._record_bytes(rec))

    def _record_bytes(self, rec) -> bytes:
        b = self._builder()
        rec.write(b)
        return b.end()

    def _chunk_record(self, rec) -> None:
        data = self._record_bytes(rec)
        self._parts.append(data)
        self._size += len(data)

    def start(self, profile: str = "", library: str = "") -> None:
        from mcap.records import Header

        self._write(MAGIC)
        self._write_record(Header(profile=profile, library=library))

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        from mcap.records import Metadata, MetadataIndex

        self.flush()  # metadata lives between chunks
        raw = self._record_bytes(Metadata(name=name, metadata=data))
        self._metadata_indexes.append(MetadataIndex(offset=self._f.tell(), length=len(raw), name=name))
        self._write(raw)

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        from mcap.records import Schema

        schema = Schema(id=len(self._schemas) + 1, name=name, encoding=encoding, data=data)
        self._schemas.append(schema)
        self._chunk_record(schema)  # also in the data section, for readers of a truncated file
        return schema.id

    def register_channel(self, topic: str, message_encoding: str, schema_id: int) -> int:
        from mcap.records import Channel

        channel = Channel(id=len(self._channels) + 1, topic=topic, message_encoding=message_encoding,
                          schema_id=schema_id, metadata={})
        self._channels.append(channel)
        self._counts[channel.id] = 0
        self._chunk_record(channel)
        return channel.id

    # -- messages ---------------------------------------------------------------------------------
    def _headers(self, channel: int, times: np.ndarray, lengths) -> np.ndarray:
        """(n,) Message record headers of ``channel`` (data lengths ``lengths``); sequences go on."""
        n = len(times)
        head = np.empty(n, dtype=_MSG_HEADER)
        head["op"] = _OP_MESSAGE
        head["length"] = np.asarray(lengths, dtype=np.uint64) + _MSG_FIXED
        head["channel"] = channel
        seq0 = self._counts[channel]
        head["sequence"] = np.arange(seq0, seq0 + n, dtype=np.uint64)
        head["log_time"] = times
        head["publish_time"] = times
        return head

    def _append(self, channel: int, times: np.ndarray, blob: bytes, sizes: np.ndarray) -> None:
        """Add the records ``blob`` (record sizes ``sizes``, times ``times``) to the open chunk and its index."""
        offsets = np.uint64(self._size) + np.concatenate((np.zeros(1, np.uint64), np.cumsum(sizes)[:-1]))
        self._index.setdefault(channel, []).append(np.column_stack([times, offsets]))
        self._parts.append(blob)
        self._size += len(blob)
        self._counts[channel] += len(times)  # last: a batch that failed before here used no sequence numbers
        lo, hi = int(times.min()), int(times.max())
        self._t0 = lo if self._t0 is None else min(self._t0, lo)
        self._t1 = hi if self._t1 is None else max(self._t1, hi)

    def add_messages(self, channel: int, log_times, datas: list[bytes]) -> None:
        """Append len(datas) messages of ``channel`` to the open chunk.

        log_times: (n,) int ns, also used as publish times; sequences continue the channel's count.
        """
        n = len(datas)
        if n == 0:
            return
        times = np.asarray(log_times, dtype=np.uint64)
        lengths = np.fromiter(map(len, datas), dtype=np.uint64, count=n)
        hb = self._headers(channel, times, lengths).tobytes()
        w = _MSG_HEADER.itemsize
        parts = [b""] * (2 * n)
        parts[0::2] = [hb[i:i + w] for i in range(0, n * w, w)]
        parts[1::2] = datas
        self._append(channel, times, b"".join(parts), lengths + np.uint64(w))

    def add_fixed_messages(self, channel: int, log_times, payloads: np.ndarray) -> None:
        """Append n messages of one fixed size: payloads is an (n,) structured array, one message
        per element (logs/encoding.LoopLayout). Header and data go through one NumPy array."""
        n = len(payloads)
        if n == 0:
            return
        times = np.asarray(log_times, dtype=np.uint64)
        size = payloads.dtype.itemsize
        rec = np.empty(n, dtype=np.dtype({"names": ["head", "data"], "formats": [_MSG_HEADER, f"V{size}"],
                                          "offsets": [0, _MSG_HEADER.itemsize],
                                          "itemsize": _MSG_HEADER.itemsize + size}))
        rec["head"] = self._headers(channel, times, np.full(n, size, np.uint64))
        rec["data"] = payloads.view(f"V{size}")
        self._append(channel, times, rec.tobytes(), np.full(n, rec.dtype.itemsize, np.uint64))

    def add_message(self, channel: int, log_time: int, data: bytes) -> None:
        self.add_messages(channel, [log_time], [data])

    def flush(self) -> None:
        """End the open chunk (if it holds anything): write it and its message indexes, flush the file."""
        from mcap.records import Chunk, ChunkIndex

        if self._parts:
            raw = b"".join(self._parts)
            if self._compression == "zstd":
                data = self._zstd.compress(raw)
            elif self._compression == "lz4":
                import lz4.frame

                data = lz4.frame.compress(raw)
            else:
                data = raw
            t0 = self._t0 or 0
            t1 = self._t1 or 0
            chunk = Chunk(compression=self._compression, data=data, message_start_time=t0, message_end_time=t1,
                          uncompressed_crc=zlib.crc32(raw), uncompressed_size=len(raw))
            b = self._builder()
            chunk.write(b)
            chunk_bytes = b.end()
            chunk_start = self._f.tell()
            self._write(chunk_bytes)
            index_start = self._f.tell()
            offsets = {}
            blobs = []
            pos = index_start
            for ch in sorted(self._index):
                pairs = np.concatenate(self._index[ch]).astype("<u8").tobytes()
                body = struct.pack("<HI", ch, len(pairs)) + pairs
                rec = struct.pack("<BQ", _OP_MESSAGE_INDEX, len(body)) + body
                offsets[ch] = pos
                pos += len(rec)
                blobs.append(rec)
            self._write(b"".join(blobs))
            self._chunk_indexes.append(self._record_bytes(ChunkIndex(
                message_start_time=t0, message_end_time=t1, chunk_start_offset=chunk_start,
                chunk_length=len(chunk_bytes), message_index_offsets=offsets, message_index_length=pos - index_start,
                compression=self._compression, compressed_size=len(data), uncompressed_size=len(raw))))
            if self._t0 is not None:
                self._t_first = t0 if self._t_first is None else min(self._t_first, t0)
                self._t_last = t1 if self._t_last is None else max(self._t_last, t1)
            self._n_chunks += 1
            for ch, pairs in self._index.items():  # the statistics count what reached the file
                self._written[ch] = self._written.get(ch, 0) + sum(len(p) for p in pairs)
            self._parts, self._size, self._index, self._t0, self._t1 = [], 0, {}, None, None
        self._f.flush()
        self._mark()

    def finish(self) -> None:
        """End the data section and write the summary, footer and closing magic. The chunk indexes
        are copied from their temporary file block by block (the summary's CRC-32 computed as it goes)."""
        from mcap.opcode import Opcode
        from mcap.records import DataEnd, Footer, Statistics, SummaryOffset

        self.flush()
        self._f.write(self._record_bytes(DataEnd(data_section_crc=self._data_crc)))
        summary_start = self._f.tell()
        crc, size, offsets = 0, 0, []

        def write(data: bytes) -> None:
            nonlocal crc, size
            crc = zlib.crc32(data, crc)
            size += len(data)
            self._f.write(data)

        def group(opcode, blocks):
            start = size
            for data in blocks:
                write(data)
            offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + start,
                                         group_length=size - start))

        stats = Statistics(
            message_count=sum(self._written.values()), schema_count=len(self._schemas),
            channel_count=len(self._channels), attachment_count=0, metadata_count=len(self._metadata_indexes),
            chunk_count=self._n_chunks, message_start_time=self._t_first or 0, message_end_time=self._t_last or 0,
            channel_message_counts={ch: n for ch, n in self._written.items() if n})
        group(Opcode.SCHEMA, map(self._record_bytes, self._schemas))
        group(Opcode.CHANNEL, map(self._record_bytes, self._channels))
        group(Opcode.STATISTICS, [self._record_bytes(stats)])
        group(Opcode.CHUNK_INDEX, self._chunk_indexes.blocks())
        group(Opcode.METADATA_INDEX, map(self._record_bytes, self._metadata_indexes))
        offset_start = summary_start + size
        for off in offsets:
            write(self._record_bytes(off))
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, offset_start), crc)
        self._f.write(self._record_bytes(Footer(summary_start=summary_start, summary_offset_start=offset_start,
                                                summary_crc=crc)))
        self._f.write(MAGIC)
        self._f.flush()
        self._chunk_indexes.close()
