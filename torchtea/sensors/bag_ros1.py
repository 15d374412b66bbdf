"""A ROS 1 bag's own index, read without decoding a record per message: the topics and message counts, and the
bytes of one topic's messages chunk by chunk, for :mod:`.bag_arrays`.

The layout (ROS wiki, "Bag Format 2.0"): after the ``#ROSBAG V2.0`` line, a bag header record gives where the
index starts (``index_pos``) and how many connections and chunks there are; at ``index_pos`` lie the connection
records (``op`` 7: the connection's id, its topic, and in its data the connection header with the message ``type``)
and then the chunk info records (``op`` 6: where a chunk is and, in its data, how many messages of each connection
it holds). Each chunk record (``op`` 5: its compression and uncompressed size) is followed in the file by one index
data record per connection it holds (``op`` 4, version 1: in its data ``count`` entries of the receive time's
seconds and nanoseconds and the message record's offset in the uncompressed chunk, three uint32 each). Every record
is a header (its length, then ``name=value`` fields each with its length) and data (its length, then the bytes).

:class:`Ros1Index` reads those records alone — a few per chunk — where ``rosbags`` builds an object for every
message's index entry when it opens a bag, which costs more than decoding the messages themselves. Anything it does
not know (another version, an unindexed bag, a compression other than none, bz2 or lz4, an index that does not add
up; a ``ValueError`` where found while the chunks are read) makes :func:`ros1_index` return None, and the bag is opened by ``rosbags``; the message-by-message reading (a
topic the array path does not decode) always goes through ``rosbags``."""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

__all__ = ["Ros1Index", "ros1_index"]

_MAGIC = b"#ROSBAG V2.0\n"


class _Unreadable(ValueError):
    """The index is not one this reader knows: the bag is left to ``rosbags``."""


class _Connection:
    """What :mod:`.bags` reads of a connection (the attributes of ``rosbags``' own)."""

    def __init__(self, cid: int, topic: str, msgtype: str, owner: Ros1Index):
        self.id, self.topic, self.msgtype, self.owner, self.msgcount = cid, topic, msgtype, owner, 0


def ros1_index(path, opener) -> Ros1Index | None:
    """The index of the ROS 1 bag at ``path`` (:class:`Ros1Index`), or None where it is not a ``.bag`` file whose
    index this module reads. ``opener(path)``: opens it with ``rosbags`` for what this module does not read."""
    path = Path(path)
    if path.suffix != ".bag" or not path.is_file():
        return None
    try:
        return Ros1Index(path, opener)
    except (_Unreadable, OSError, struct.error, ValueError, UnicodeDecodeError):
        return None


def _fields(header: bytes) -> dict:
    out, pos = {}, 0
    while pos < len(header):
        (n,) = struct.unpack_from("<I", header, pos)
        field = header[pos + 4:pos + 4 + n]
        if len(field) != n or b"=" not in field:
            raise _Unreadable("a header field is cut")
        name, value = field.split(b"=", 1)
        out[name.decode()] = value
        pos += 4 + n
    return out


def _decompressor(name: str):
    if name == "none":
        return lambda b: b
    if name == "bz2":
        import bz2

        return bz2.decompress
    if name == "lz4":
        from lz4.frame import decompress  # (a dependency of rosbags)

        return decompress
    raise _Unreadable(f"compression {name!r}")


def _u32(fields: dict, name: str) -> int:
    return struct.unpack("<I", fields[name])[0]


class Ros1Index:
    """A ROS 1 bag's connections and chunks (module docstring); ``connections`` as :mod:`.bags` reads a
    ``rosbags`` reader's. ``chunks(ids)`` yields, per chunk holding messages of the connections ``ids``, its
    uncompressed bytes and the receive times and record offsets of those messages."""

    #: (what :mod:`.bag_arrays` asks of a connection's owner: its messages' bytes come from :meth:`chunks`)
    own_index = True

    def __init__(self, path: Path, opener):
        self.path, self._opener = path, opener
        self._f = open(path, "rb")
        self._fallback = None
        try:
            self._read()
        except BaseException:
            self._f.close()
            raise

    def _record(self) -> tuple[dict, int]:
        """The record at the file's position: its header's fields, and its data's length (the file left there)."""
        (n,) = struct.unpack("<I", self._read_exact(4))
        fields = _fields(self._read_exact(n))
        (m,) = struct.unpack("<I", self._read_exact(4))
        return fields, m

    def _read_exact(self, n: int) -> bytes:
        b = self._f.read(n)
        if len(b) != n:
            raise _Unreadable("the file ends inside a record")
        return b

    def _read(self) -> None:
        f = self._f
        if f.read(len(_MAGIC)) != _MAGIC:
            raise _Unreadable("not a version 2.0 bag")
        head, _ = self._record()
        if head.get("op") != b"\x03":
            raise _Unreadable("no bag header record")
        (index_pos,) = struct.unpack("<Q", head["index_pos"])
        conn_count, chunk_count = _u32(head, "conn_count"), _u32(head, "chunk_count")
        if index_pos == 0:
            raise _Unreadable("an unindexed bag")
        f.seek(index_pos)
        self.connections, by_id = [], {}
        for _ in range(conn_count):
            fields, m = self._record()
            if fields.get("op") != b"\x07":
                raise _Unreadable("not a connection record")
            conn = _fields(self._read_exact(m))
            msgtype = conn["type"].decode()
            pkg, _, name = msgtype.partition("/")
            c = _Connection(_u32(fields, "conn"), fields["topic"].decode(), f"{pkg}/msg/{name}", self)
            by_id[c.id] = c
            self.connections.append(c)
        self._chunks = []  # (chunk_pos, {conn: count})
        for _ in range(chunk_count):
            fields, m = self._record()
            if fields.get("op") != b"\x06" or _u32(fields, "ver") != 1:
                raise _Unreadable("not a version 1 chunk info record")
            pairs = np.frombuffer(self._read_exact(m), dtype="<u4").reshape(-1, 2)
            if len(pairs) != _u32(fields, "count"):
                raise _Unreadable("a chunk info record's count")
            counts = {int(c): int(k) for c, k in pairs}
            for c, k in counts.items():
                if c not in by_id:
                    raise _Unreadable("a chunk of an unknown connection")
                by_id[c].msgcount += k
            self._chunks.append((struct.unpack("<Q", fields["chunk_pos"])[0], counts))
        # (rosbags lists a bag's connections by id)
        self.connections.sort(key=lambda c: c.id)

    def chunks(self, ids):
        """Per chunk holding messages of ``ids``: ``(its position, bytes (np.uint8), times ns (k,), offsets (k,))``,
        the messages' receive times and their records' offsets in the uncompressed chunk, each connection's in its index's
        order."""
        f, ids = self._f, set(ids)
        for pos, counts in self._chunks:
            if not ids & counts.keys():
                continue
            f.seek(pos)
            fields, m = self._record()
            if fields.get("op") != b"\x05":
                raise _Unreadable("not a chunk record")
            size = _u32(fields, "size")
            data = _decompressor(fields["compression"].decode())(self._read_exact(m))
            if len(data) != size:
                raise _Unreadable("a chunk's size")
            times, offsets = [], []
            for _ in range(len(counts)):
                head, n = self._record()
                if head.get("op") != b"\x04" or _u32(head, "ver") != 1:
                    raise _Unreadable("not a version 1 index data record")
                cid, count = _u32(head, "conn"), _u32(head, "count")
                raw = self._read_exact(n)
                if cid not in ids:
                    continue
                if n != 12 * count or count != counts.get(cid):
                    raise _Unreadable("an index data record's count")
                e = np.frombuffer(raw, dtype="<u4").reshape(-1, 3).astype(np.int64)
                times.append(e[:, 0] * 1_000_000_000 + e[:, 1])
                offsets.append(e[:, 2])
            yield pos, np.frombuffer(data, dtype=np.uint8), np.concatenate(times), np.concatenate(offsets)

    # what .bags reads of a rosbags reader beyond the connections: the message-by-message path, through rosbags

    def _rosbags(self):
        if self._fallback is None:
            self._fallback = self._opener(self.path)
        return self._fallback

    def messages(self, connections):
        reader = self._rosbags()
        topics = {c.topic for c in connections}
        yield from reader.messages(connections=[c for c in reader.connections if c.topic in topics])

    def deserialize(self, raw, msgtype):
        return self._rosbags().deserialize(raw, msgtype)

    def close(self) -> None:
        self._f.close()
        if self._fallback is not None:
            self._fallback.close()
