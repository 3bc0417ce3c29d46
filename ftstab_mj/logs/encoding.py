"""Binary encoding of the loop samples: one protobuf message per sample, built for a whole batch by NumPy.

Foxglove, Rerun's MCAP loader, the ``mcap`` CLI and ``mcap-protobuf-support`` all decode protobuf
from the schema stored in the file (schema encoding "protobuf": a FileDescriptorSet). The message
``ftstab.LoopSample`` is derived from the fields a loop's batch carries, in their order: a field of
shape (n,) is a ``double``, a field of shape (n, w) (the state z, and any other per-coordinate
field) a ``repeated double`` (packed, proto3's default). Field numbers are 1, 2, ... in that order.

Every sample is written in one *fixed layout*: each field present, scalars as tag + 8 bytes, vectors
as tag + length + 8 w bytes, even when a value is 0 (proto3 writers usually omit zeros; parsers
accept both). So every message of a loop has the same length, a batch is one structured NumPy array
(:class:`LoopLayout`), and reading a log back is one ``np.frombuffer`` per loop after the tags
are checked. Doubles are stored as they are: NaN and infinities survive (JSON had to write null).
"""

from __future__ import annotations

import numpy as np

SCHEMA_NAME = "ftstab.LoopSample"
PROTO_FILE = "ftstab/LoopSample.proto"
MAX_FIELDS = 64  # a loop with more fields is not one of ours (a bound for untrusted schemas)
MAX_WIDTH = 64  # values of one vector field (r, or a per-coordinate field)
_WIRE_I64, _WIRE_LEN = 1, 2


def varint(v: int) -> bytes:
    out = bytearray()
    while True:
        b = v & 0x7F
        v >>= 7
        out.append(b | (0x80 if v else 0))
        if not v:
            return bytes(out)


class LoopLayout:
    """The fixed protobuf layout of one loop's samples.

    fields: ((name, width), ...) in field-number order; width 0 = a scalar double, w >= 1 = a packed
    repeated double of exactly w values. ``dtype`` is the structured dtype of one message (tags
    as raw bytes between the values); ``template`` one message with every value 0.
    """

    def __init__(self, fields, numbers=None):
        self.fields = tuple((str(n), int(w)) for n, w in fields)
        self.numbers = tuple(numbers) if numbers is not None else tuple(range(1, len(self.fields) + 1))
        names, formats, offsets, template = [], [], [], bytearray()
        for (name, width), number in zip(self.fields, self.numbers):
            if width == 0:
                template += varint(number << 3 | _WIRE_I64)
                fmt = "<f8"
            else:
                template += varint(number << 3 | _WIRE_LEN) + varint(8 * width)
                fmt = ("<f8", (width,))
            names.append(name)
            formats.append(fmt)
            offsets.append(len(template))
            template += bytes(8 * max(width, 1))
        self.template = bytes(template)
        self.size = len(template)
        self.dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": self.size})
        # positions of the tag/length bytes (everything that is not a value): what a reader checks
        is_value = np.zeros(self.size, bool)
        for name in names:
            off = self.dtype.fields[name][1]
            is_value[off:off + self.dtype.fields[name][0].itemsize] = True
        self._tag_pos = np.flatnonzero(~is_value)

    @classmethod
    def of_batch(cls, arrays: dict) -> "LoopLayout":
        """The layout of a batch {field: (n,) or (n, w) array}, fields in the dict's order."""
        fields = []
        for name, a in arrays.items():
            a = np.asarray(a)
            if a.ndim not in (1, 2):
                raise ValueError(f"loop field {name}: expected shape (n,) or (n, w), found {a.shape}")
            fields.append((name, 0 if a.ndim == 1 else a.shape[1]))
        return cls(fields)

    def encode(self, arrays: dict) -> np.ndarray:
        """(n,) structured array of ``dtype``: the n messages of a batch, back to back in .tobytes()."""
        n = len(arrays[self.fields[0][0]])
        out = np.empty(n, dtype=self.dtype)
        out.view(np.uint8).reshape(n, self.size)[:] = np.frombuffer(self.template, np.uint8)
        for name, _ in self.fields:
            out[name] = arrays[name]
        return out

    def decode(self, blob: bytes, n: int) -> dict | None:
        """{field: (n,) or (n, w) float array} of n messages laid out back to back in ``blob``, or
        None when they are not all in this fixed layout (then decode them one by one)."""
        if len(blob) != n * self.size:
            return None
        raw = np.frombuffer(blob, np.uint8).reshape(n, self.size)
        if n and not np.array_equal(raw[:, self._tag_pos], np.broadcast_to(
                np.frombuffer(self.template, np.uint8)[self._tag_pos], (n, len(self._tag_pos)))):
            return None
        rec = np.frombuffer(blob, dtype=self.dtype, count=n)
        return {name: np.array(rec[name], dtype=float) for name, _ in self.fields}

    def file_descriptor_set(self) -> bytes:
        """The schema as Foxglove expects it: a serialized google.protobuf.FileDescriptorSet."""
        from google.protobuf import descriptor_pb2 as d

        fds = d.FileDescriptorSet()
        f = fds.file.add(name=PROTO_FILE, package=SCHEMA_NAME.split(".")[0], syntax="proto3")
        msg = f.message_type.add(name=SCHEMA_NAME.split(".")[1])
        for (name, width), number in zip(self.fields, self.numbers):
            msg.field.add(name=name, number=number, type=d.FieldDescriptorProto.TYPE_DOUBLE,
                          label=(d.FieldDescriptorProto.LABEL_REPEATED if width else d.FieldDescriptorProto.LABEL_OPTIONAL))
        return fds.SerializeToString()


def layout_from_schema(data: bytes, what: str, first: bytes | None = None):
    """(LoopLayout, message class) from a log's FileDescriptorSet of ``ftstab.LoopSample``.

    first: the first message of the channel; the width of each repeated field is taken from it.
    Raises ValueError naming what is wrong when the schema is not a flat message of doubles.
    The message class (google.protobuf) decodes messages that are not in the fixed layout.
    """
    from google.protobuf import descriptor_pb2 as d
    from google.protobuf import descriptor_pool, message_factory

    try:
        fds = d.FileDescriptorSet.FromString(data)
    except Exception:
        raise ValueError(f"{what}: the schema is not a protobuf FileDescriptorSet") from None
    found = [(f, m) for f in fds.file for m in f.message_type if f"{f.package}.{m.name}" == SCHEMA_NAME]
    if len(found) != 1 or len(fds.file) != 1:
        raise ValueError(f"{what}: expected one file defining {SCHEMA_NAME}, found {len(fds.file)} file(s)")
    file, msg = found[0]
    if len(msg.field) > MAX_FIELDS:
        raise ValueError(f"{what}: expected at most {MAX_FIELDS} fields in {SCHEMA_NAME}, found {len(msg.field)}")
    for fd in msg.field:
        if fd.type != d.FieldDescriptorProto.TYPE_DOUBLE:
            raise ValueError(f"{what}: field {fd.name}: expected a double, found protobuf type {fd.type}")
    try:
        pool = descriptor_pool.DescriptorPool()
        pool.Add(file)
        cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(SCHEMA_NAME))
        sample = cls.FromString(first) if first is not None else None
    except Exception as exc:
        raise ValueError(f"{what}: the schema does not build or the first message does not decode "
                         f"({type(exc).__name__})") from None
    fields = []
    for fd in msg.field:
        w = 0
        if fd.label == d.FieldDescriptorProto.LABEL_REPEATED:
            w = len(getattr(sample, fd.name)) if sample is not None else 1
            if not 1 <= w <= MAX_WIDTH:
                raise ValueError(f"{what}: field {fd.name}: expected 1 to {MAX_WIDTH} values, found {w}")
        fields.append((fd.name, w))
    return LoopLayout(fields, [fd.number for fd in msg.field]), cls


def decode_each(layout: LoopLayout, cls, datas: list[bytes], what: str) -> dict:
    """Slow path: decode messages one by one (any valid protobuf encoding of the schema)."""
    out = {name: np.full((len(datas), w) if w else len(datas), np.nan) for name, w in layout.fields}
    for i, data in enumerate(datas):
        try:
            m = cls.FromString(data)
        except Exception:
            raise ValueError(f"{what}: message {i} is not a valid {SCHEMA_NAME}") from None
        for name, w in layout.fields:
            v = getattr(m, name)
            if w:
                if len(v) != w:
                    raise ValueError(f"{what}: message {i}: field {name}: expected {w} values, found {len(v)}")
                out[name][i] = list(v)
            else:
                out[name][i] = v
    return out
