"""``sensor_msgs/Imu`` and ``sensor_msgs/Temperature`` messages of a ROS bag decoded at array speed: the messages'
bytes gathered from the bag's own index without decoding one message at a time, and the fields a recording needs —
the header stamp, the linear acceleration and the angular velocity, or the temperature — read from all of them at
once with NumPy.

Where the bytes come from (through the ``rosbags`` readers' open bags):

* ROS 1 ``.bag``: each chunk decompressed once, the messages at the offsets of the bag's index data records (the
  reader's ``indexes``), each a message data record — header length, header, data length, data (ROS wiki, "Bag
  Format 2.0");
* ROS 2 ``.db3``: one SQL query of the topic's rows in time order;
* ``.mcap``: each chunk decompressed once, the messages at the offsets of the chunk's message index records (the MCAP
  specification, "Message Index" and "Message" records).

How a message is laid out: ROS 1 serialisation writes ``seq``, the stamp's ``sec``/``nsec`` (uint32), the frame
id's length and bytes, then the float64 fields without padding; CDR (ROS 2, little-endian) writes a 4-byte
encapsulation header, the stamp's ``sec`` (int32) and ``nanosec``, the frame id's length (its NUL included) and
bytes, padding to 8 bytes from the payload's start, then the float64 fields — for an Imu the orientation (4), its
covariance (9), the angular velocity (3), its covariance, the linear acceleration (3), its covariance; for a
Temperature the temperature and its variance. Every message's length is
checked against that layout. Anything else — a compression or storage the readers do not expose, a big-endian CDR
message, an index that points elsewhere, a length that does not fit — returns None, and the bag is read one message
at a time by the generic path (:mod:`.bags`); the tests hold the two to each other on every format."""
from __future__ import annotations

import numpy as np

__all__ = ["imu_arrays", "temperature_arrays"]

#: Where the float64 values a recording needs lie after a message's frame id (bytes), and the bytes from there to the
#: message's end: an Imu's linear acceleration (after the orientation, its covariance, the angular velocity and its
#: covariance) and angular velocity (after the orientation and its covariance); a Temperature's temperature (its
#: variance after it).
_IMU = ((200, 208, 216, 104, 112, 120), 296)
_TEMPERATURE = ((0,), 16)


def imu_arrays(reader, connections) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """``(header stamps ns (N,), receive times ns (N,), values (N, 6))`` of the ``sensor_msgs/Imu`` messages of
    ``connections`` (one topic) in the open ``rosbags`` ``reader`` (``AnyReader``), in the order the generic reader
    yields them (receive time); the values' columns: the linear acceleration's x, y, z, the angular velocity's x, y,
    z. None where the bag's storage or a message's layout has no array path (the caller reads it message by
    message)."""
    return _arrays(reader, connections, _IMU)


def temperature_arrays(reader, connections) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """As :func:`imu_arrays`, of ``sensor_msgs/Temperature`` messages: values ``(N, 1)``, the temperature (°C)."""
    return _arrays(reader, connections, _TEMPERATURE)


def _arrays(reader, connections, layout):
    if connections and all(getattr(c.owner, "own_index", False) for c in connections):
        return _indexed(connections[0].owner, [c.id for c in connections], layout)
    raw = _gather(reader, connections)
    if raw is None:
        return None
    received, buf, starts, lengths, ros1 = raw
    if not len(starts):
        return None
    decoded = (_decode_ros1 if ros1 else _decode_cdr)(buf, starts, lengths, layout)
    if decoded is None:
        return None
    stamps, values = decoded
    return stamps, received, values


def _u32(buf: np.ndarray, pos: np.ndarray) -> np.ndarray:
    return buf[pos[:, None] + np.arange(4)].view("<u4").reshape(-1).astype(np.int64)


def _u64(buf: np.ndarray, pos: np.ndarray) -> np.ndarray:
    return buf[pos[:, None] + np.arange(8)].view("<u8").reshape(-1).astype(np.int64)


def _f64(buf: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """The float64 at each position of ``pos`` ``(N, k)`` → ``(N, k)``."""
    return buf[pos[..., None] + np.arange(8)].view("<f8")[..., 0]


def _decode_ros1(buf, starts, lengths, layout):
    offsets, tail = layout
    length = _u32(buf, starts + 12)
    base = starts + 16 + length
    if np.any(base + tail != starts + lengths):
        return None
    stamps = _u32(buf, starts + 4) * 1_000_000_000 + _u32(buf, starts + 8)
    return stamps, _f64(buf, base[:, None] + np.array(offsets))


def _decode_cdr(buf, starts, lengths, layout):
    offsets, tail = layout
    if np.any(buf[starts] != 0) or np.any(buf[starts + 1] != 1):  # (CDR little-endian only)
        return None
    payload = starts + 4
    length = _u32(buf, payload + 8)
    base = payload + (12 + length + 7) // 8 * 8
    if np.any(base + tail != starts + lengths):
        return None
    sec = buf[payload[:, None] + np.arange(4)].view("<i4").reshape(-1).astype(np.int64)
    stamps = sec * 1_000_000_000 + _u32(buf, payload + 4)
    return stamps, _f64(buf, base[:, None] + np.array(offsets))


def _gather(reader, connections):
    """``(receive times (N,), bytes (np.uint8), starts (N,), lengths (N,), ros1)`` of the messages of
    ``connections`` in the generic reader's order, or None."""
    from rosbags.rosbag1 import Reader as Reader1

    owners = {id(c.owner): c.owner for c in connections}
    if len(owners) != 1:  # (a topic over several bags: the generic path merges them)
        return None
    owner = next(iter(owners.values()))
    if isinstance(owner, Reader1):
        return _ros1(owner, [c.id for c in connections])
    storages = getattr(owner, "storages", None)  # (a ROS 2 bag's reader, over its storage files)
    if storages is not None and len(storages) == 1 and getattr(owner.metadata, "compression_mode", "") != "message":
        storage = owner.storages[0]
        mine = [x for x in storage.connections
                if any(x.topic == c.topic and x.msgtype == c.msgtype for c in connections)]
        if hasattr(storage, "dbconn"):
            return _sqlite(storage, [x.id for x in mine])
        if hasattr(storage, "chunks"):
            return _mcap(storage, [x.id for x in mine])
    return None


def _ros1(bag, ids: list):
    entries = [e for cid in ids for e in bag.indexes.get(cid, ())]
    if not entries:
        return None
    time = np.fromiter((e.time for e in entries), dtype=np.int64, count=len(entries))
    chunk = np.fromiter((e.chunk_pos for e in entries), dtype=np.int64, count=len(entries))
    offset = np.fromiter((e.offset for e in entries), dtype=np.int64, count=len(entries))
    order = np.lexsort((offset, chunk, time))  # (the generic reader's order: time, chunk, offset)
    time, chunk, offset = time[order], chunk[order], offset[order]
    pieces, base, where = [], 0, {}
    for pos in np.unique(chunk).tolist():
        info = bag.chunks[pos]
        bag.bio.seek(info.datapos)
        data = bag.bio.read(info.datasize)
        if len(data) != info.datasize:
            return None
        data = info.decompressor(data)
        where[pos] = base
        pieces.append(data)
        base += len(data)
    buf = np.frombuffer(b"".join(pieces), dtype=np.uint8)
    rec = offset + np.array([where[p] for p in chunk.tolist()], dtype=np.int64)
    found = _ros1_records(buf, rec, ids)
    return None if found is None else (time, buf, *found, True)


def _ros1_records(buf: np.ndarray, rec: np.ndarray, ids) -> tuple[np.ndarray, np.ndarray] | None:
    """The data's starts and lengths of the ROS 1 message data records at ``rec`` in ``buf``, or None where one is
    not a message data record of the connections ``ids``."""
    if np.any(rec + 4 > len(buf)):
        return None
    header = _u32(buf, rec)
    if np.any(header != header[0]) or np.any(rec + 8 + header > len(buf)):
        return None
    # every record's header must be a message data record's (op 2) of these connections: the fields of the first,
    # at the same places in all (an index entry that points at a connection record is left to the generic path)
    first = bytes(buf[rec[0] + 4:rec[0] + 4 + header[0]])
    at_op = first.find(b"op=\x02")
    at_conn = first.find(b"conn=")
    if at_op < 0 or at_conn < 0:
        return None
    if np.any(buf[rec + 4 + at_op + 3] != 2) or not np.isin(_u32(buf, rec + 4 + at_conn + 5), ids).all():
        return None
    length = _u32(buf, rec + 4 + header)
    starts = rec + 8 + header
    if np.any(starts + length > len(buf)):
        return None
    return starts, length


def _indexed(index, ids: list, layout):
    """:func:`_arrays` of a ROS 1 bag read by its own index (:class:`~.bag_ros1.Ros1Index`): each chunk decoded as
    it is read (one chunk's bytes held at a time), then all in the generic reader's order (time, chunk, offset); None
    where the index does not add up (its ``ValueError``)."""
    parts = []
    try:
        for pos, buf, time, offset in index.chunks(ids):
            found = _ros1_records(buf, offset, ids)
            decoded = None if found is None else _decode_ros1(buf, *found, layout)
            if decoded is None:
                return None
            parts.append((time, np.full(len(time), pos, dtype=np.int64), offset, *decoded))
    except ValueError:
        return None
    if not parts:
        return None
    time, chunk, offset, stamps, values = (np.concatenate(x) for x in zip(*parts))
    order = np.lexsort((offset, chunk, time))
    return stamps[order], time[order], values[order]


def _sqlite(storage, ids: list):
    import sqlite3

    path = getattr(storage, "path", None)
    if not ids or path is None:
        return None
    con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)  # (the standard library's driver: half the time per row)
    try:
        rows = con.execute(f"SELECT timestamp, data FROM messages WHERE topic_id IN ({','.join('?' for _ in ids)}) "
                           "ORDER BY timestamp", tuple(ids)).fetchall()
    except sqlite3.Error:
        return None
    finally:
        con.close()
    if not rows:
        return None
    time = np.fromiter((r[0] for r in rows), dtype=np.int64, count=len(rows))
    datas = [r[1] for r in rows]
    length = np.fromiter(map(len, datas), dtype=np.int64, count=len(datas))
    starts = np.zeros(len(datas), dtype=np.int64)
    np.cumsum(length[:-1], out=starts[1:])
    return time, np.frombuffer(b"".join(datas), dtype=np.uint8), starts, length, False


def _mcap(storage, ids: list):
    from rosbags.rosbag2.storage_mcap import decompress

    if not storage.chunks or not ids:
        return None
    bio = storage.bio
    pieces, times, recs, base = [], [], [], 0
    for chunk in storage.chunks:
        index = []
        for cid in ids:
            at = chunk.message_index_offsets.get(cid)
            if at is None:
                continue
            bio.seek(at)
            head = bio.read(15)
            if len(head) != 15 or head[0] != 0x07:
                return None
            size = int(np.frombuffer(head[11:15], dtype="<u4")[0])
            pairs = np.frombuffer(bio.read(size), dtype="<u8").reshape(-1, 2).astype(np.int64)
            index.append(pairs)
        if not index:
            continue
        bio.seek(chunk.chunk_start_offset + 9 + 24)
        crc = int(np.frombuffer(bio.read(4), dtype="<u4")[0])
        bio.seek(chunk.chunk_start_offset + 9 + 40 + len(chunk.compression))
        data = decompress(bio.read(chunk.compressed_size), chunk.compression, chunk.uncompressed_size, crc)
        pairs = np.concatenate(index)
        pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]  # (in the chunk: by time, then as written)
        times.append(pairs[:, 0])
        recs.append(pairs[:, 1] + base)
        pieces.append(data)
        base += len(data)
    if not pieces:
        return None
    buf = np.frombuffer(b"".join(pieces), dtype=np.uint8)
    time, rec = np.concatenate(times), np.concatenate(recs)
    order = np.argsort(time, kind="stable")
    time, rec = time[order], rec[order]
    if np.any(rec + 31 > len(buf)) or np.any(buf[rec] != 0x05):
        return None
    size = _u64(buf, rec + 1)
    channel = buf[rec[:, None] + 9 + np.arange(2)].view("<u2").reshape(-1)
    if not np.isin(channel, ids).all() or np.any(size < 22) or np.any(rec + 9 + size > len(buf)):
        return None
    return time, buf, rec + 31, size - 22, False
