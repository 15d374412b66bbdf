"""Reading ROS bags: ROS 1 ``.bag``, ROS 2 ``.db3`` and ``.mcap`` (a bag's folder with its ``metadata.yaml``, or
the storage file alone), with the pure-Python `rosbags <https://gitlab.com/ternaris/rosbags>`_ reader — no ROS
install.

An IMU topic of ``sensor_msgs/Imu`` becomes a :class:`~torchtea.sensors.io.Recording` like a CSV's: the
accelerometer's ``linear_acceleration`` (m/s²) and the gyroscope's ``angular_velocity`` (rad/s) as six channels,
the messages' header stamps as time stamps (the bag's receive times where every header stamp is 0, said in the
metadata), the rate from the stamps unless given. A ``sensor_msgs/Temperature`` topic is the temperature input,
its readings (°C) interpolated onto the IMU's stamps (NaN outside its own span).

Which topic: ``topic`` names it; without, the bag's only ``sensor_msgs/Imu`` topic. Anything else — no such topic,
a topic of another type, several IMU topics and none named, no messages, header stamps that go back — is one
:class:`~torchtea.sensors.errors.InputError` naming the bag, the topic and what the bag has.

Speed and memory: an IMU topic and a temperature topic are decoded at array speed from the bag's own index
(:mod:`.bag_arrays`: a few microseconds a message, the stored bytes held once while they are decoded); where the bag's storage has no such
path, the messages are read one at a time into arrays sized from the bag's index (seven float64 per message:
56 MB an hour at 250 Hz … 0.8 GB for 3.7 h at 2 kHz, the size of the recording itself).
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .bag_arrays import imu_arrays, temperature_arrays
from .bag_ros1 import ros1_index
from .errors import InputError

__all__ = ["BAG_SUFFIXES", "IMU_TYPE", "TEMPERATURE_TYPE", "is_bag", "bag_topics", "read_bag"]

BAG_SUFFIXES = (".bag", ".db3", ".mcap")
IMU_TYPE = "sensor_msgs/msg/Imu"
TEMPERATURE_TYPE = "sensor_msgs/msg/Temperature"
#: The channels of an Imu message: (name, sensor, axis, field, component).
IMU_FIELDS = tuple((f"{fld}.{a}", sensor, a, fld, a) for sensor, fld in (("accelerometer", "linear_acceleration"),
                                                                         ("gyroscope", "angular_velocity"))
                   for a in "xyz")
_LABELS = {"accelerometer": "a", "gyroscope": "g"}


def is_bag(path) -> bool:
    """A ROS bag: a ``.bag``, ``.db3`` or ``.mcap`` file, or a ROS 2 bag's folder (it has ``metadata.yaml``)."""
    p = Path(path)
    return p.suffix in BAG_SUFFIXES or (p.is_dir() and (p / "metadata.yaml").is_file())


def _reader(path: Path):
    from rosbags.highlevel import AnyReader, AnyReaderError

    if not path.exists():
        raise InputError(f"{path}: no such file or folder")
    try:
        reader = AnyReader([path])
        reader.open()
    except (AnyReaderError, OSError, ValueError, KeyError) as exc:
        raise InputError(f"{path}: not a readable ROS bag ({type(exc).__name__}: {exc})") from None
    except Exception as exc:  # (rosbags on a damaged file: a size field read as gigabytes, a record cut short …)
        raise InputError(f"{path}: not a readable ROS bag, damaged ({type(exc).__name__}: {exc})") from None
    return reader


def _open(path: Path):
    """The bag opened: a ROS 1 bag by its own index where it can be (:mod:`.bag_ros1`), else by ``rosbags``."""
    return ros1_index(path, _reader) or _reader(path)


def bag_topics(path) -> list[tuple[str, str, int]]:
    """The bag's topics: ``(topic, message type, messages)``, sorted by topic."""
    path = Path(path)
    reader = _open(path)
    try:
        return _topics(reader)
    finally:
        reader.close()


def _topics(reader) -> list[tuple[str, str, int]]:
    out = {}
    for c in reader.connections:
        t, n = out.get(c.topic, (c.msgtype, 0))
        out[c.topic] = (t, n + c.msgcount)
    return sorted((topic, t, n) for topic, (t, n) in out.items())


def _listing(topics) -> str:
    return ", ".join(f"{topic} ({t.replace('/msg/', '/')}, {n} messages)" for topic, t, n in topics) or "no topics"


def _pick(path: Path, topics, topic: str | None, msgtype: str, what: str, option: str) -> str:
    of_type = [t for t in topics if t[1] == msgtype]
    if topic is None:
        if len(of_type) == 1:
            return of_type[0][0]
        if not of_type:
            raise InputError(f"{path}: no {msgtype.replace('/msg/', '/')} topic for the {what} (the bag has "
                             f"{_listing(topics)})")
        raise InputError(f"{path}: {len(of_type)} {msgtype.replace('/msg/', '/')} topics — choose the {what}'s with "
                         f"{option}: {_listing(of_type)}")
    found = [t for t in topics if t[0] == topic]
    if not found:
        raise InputError(f"{path}: no topic {topic!r} (the bag has {_listing(topics)})")
    if found[0][1] != msgtype:
        raise InputError(f"{path}: topic {topic!r} is {found[0][1].replace('/msg/', '/')}, not "
                         f"{msgtype.replace('/msg/', '/')} (the {what}); the bag's "
                         f"{msgtype.replace('/msg/', '/')} topics: {_listing(of_type) if of_type else 'none'}")
    if found[0][2] == 0:
        raise InputError(f"{path}: topic {topic!r} has no messages (the bag has {_listing(topics)})")
    return topic


def _stamp(msg) -> int:
    s = msg.header.stamp
    return int(s.sec) * 1_000_000_000 + int(s.nanosec)


def _read_topic(reader, path: Path, topic: str, fields, columns=None,
                arrays=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(header stamps ns, receive times ns, values (N, F))`` of every message of ``topic``: its ``columns`` of what
    ``arrays`` decodes at array speed (default :func:`~.bag_arrays.imu_arrays`: indices into :data:`IMU_FIELDS`;
    :func:`~.bag_arrays.temperature_arrays`) where the bag allows it, else read one message at a time,
    ``fields(msg)`` giving a message's values."""
    conns = [c for c in reader.connections if c.topic == topic]
    if columns is not None:
        fast = (arrays or imu_arrays)(reader, conns)
        if fast is not None:
            stamps, received, values = fast
            return stamps, received, np.ascontiguousarray(values[:, columns])
    count = sum(c.msgcount for c in conns)
    stamps = np.empty(count, dtype=np.int64)
    received = np.empty(count, dtype=np.int64)
    values = None
    k = 0
    for conn, t_ns, raw in reader.messages(connections=conns):
        msg = reader.deserialize(raw, conn.msgtype)
        v = fields(msg)
        if values is None:
            values = np.empty((count, len(v)), dtype=np.float64)
        if k >= count:  # (an index that undercounts: grow)
            stamps, received = np.resize(stamps, 2 * count + 1), np.resize(received, 2 * count + 1)
            values = np.resize(values, (2 * count + 1, values.shape[1]))
            count = 2 * count + 1
        stamps[k], received[k], values[k] = _stamp(msg), t_ns, v
        k += 1
    if k == 0:
        raise InputError(f"{path}: topic {topic!r} has no messages")
    return stamps[:k], received[:k], values[:k]


def _onto(t: np.ndarray, ts: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Readings ``v`` at times ``ts`` interpolated onto ``t``; before the first and after the last each is held for up
    to one median interval between readings (a slower topic's edges), NaN beyond (no reading there)."""
    out = np.interp(t, ts, v, left=np.nan, right=np.nan)
    step = float(np.median(np.diff(ts))) if len(ts) > 1 else 0.0
    out[(t < ts[0]) & (t >= ts[0] - step)] = v[0]
    out[(t > ts[-1]) & (t <= ts[-1] + step)] = v[-1]
    return out


def read_bag(path, *, topic: str | None = None, temperature_topic: str | None = None,
             columns: Sequence[str] | None = None) -> dict:
    """The IMU topic of a ROS bag (module docstring): ``columns`` (labels ``ax`` … ``gz`` or field names
    ``linear_acceleration.x`` …; default all six), ``temperature_topic`` a ``sensor_msgs/Temperature`` topic.
    Returns ``{"topic", "channels": [(name, sensor, axis, values (N,))], "time_s": (N,) seconds from the first
    stamp, "temperature": (N,) °C or None, "metadata"}`` — :func:`~torchtea.sensors.io.read_recording` makes the
    :class:`~torchtea.sensors.io.Recording` of it."""
    path = Path(path)
    try:
        return _read_bag(path, topic, temperature_topic, columns)
    except InputError:
        raise
    except Exception as exc:  # (a damaged bag fails inside rosbags' or the array decoders' reading in many ways)
        raise InputError(f"{path}: a damaged ROS bag: its messages cannot be read ({type(exc).__name__}: "
                         f"{exc})") from None


def _read_bag(path: Path, topic, temperature_topic, columns) -> dict:
    reader = _open(path)
    try:
        topics = _topics(reader)
        if not any(n for _, _, n in topics):
            raise InputError(f"{path}: the bag holds no messages ({_listing(topics)})")
        imu = _pick(path, topics, topic, IMU_TYPE, "IMU", "--topic")
        wanted = list(IMU_FIELDS)
        if columns:
            by = {**{f[0]: f for f in IMU_FIELDS}, **{_LABELS[f[1]] + f[2]: f for f in IMU_FIELDS}}
            lacking = [c for c in columns if c not in by]
            if lacking:
                raise InputError(f"{path}: topic {imu!r} has no column(s) {', '.join(map(repr, lacking))} (a "
                                 f"sensor_msgs/Imu gives {', '.join(by)})")
            wanted = [by[c] for c in columns]

        def imu_fields(msg):
            return [getattr(getattr(msg, fld), comp) for _, _, _, fld, comp in wanted]

        stamps, received, values = _read_topic(reader, path, imu, imu_fields,
                                               [IMU_FIELDS.index(w) for w in wanted])
        meta = {"bag": str(path), "topic": imu, "messages": int(len(stamps)), "bag_topics": _listing(topics)}
        if np.all(stamps == 0):
            stamps = received
            meta["time_source"] = (f"topic {imu!r}: every header stamp is 0; the bag's receive times are used as "
                                   "time stamps (they carry the transport's jitter)")
        else:
            meta["time_source"] = f"topic {imu!r}: the messages' header stamps"
        back = np.flatnonzero(np.diff(stamps) < 0)
        if back.size:
            i = int(back[0]) + 1
            raise InputError(f"{path}: topic {imu!r}: header stamps go back at message {i} ({stamps[i] * 1e-9:.9f} s "
                             f"after {stamps[i - 1] * 1e-9:.9f} s; {back.size} time(s) in {len(stamps)} messages) — "
                             "messages out of order; the bag is not a time series as it stands")
        t = (stamps - stamps[0]).astype(np.float64) * 1e-9
        temperature = None
        if temperature_topic is not None or any(tp == TEMPERATURE_TYPE for _, tp, _ in topics):
            try:
                ttopic = _pick(path, topics, temperature_topic, TEMPERATURE_TYPE, "temperature", "--temperature")
            except InputError:
                if temperature_topic is not None:
                    raise
                ttopic = None  # (several temperature topics and none named: no input, said in the metadata)
                meta["temperature_skipped"] = ("several sensor_msgs/Temperature topics and none named: no "
                                               "temperature input (choose one with --temperature)")
            if ttopic is not None:
                ts, tr, tv = _read_topic(reader, path, ttopic, lambda m: [m.temperature], [0], temperature_arrays)
                ts = tr if np.all(ts == 0) else ts
                order = np.argsort(ts, kind="stable")
                tsec = (ts[order] - stamps[0]).astype(np.float64) * 1e-9
                temperature = _onto(t, tsec, tv[order, 0])
                meta["temperature_topic"] = ttopic
                meta["temperature_source"] = (f"topic {ttopic!r}: {len(ts)} readings, interpolated onto the IMU's "
                                              "stamps, the first and last held for up to one of their intervals")
    finally:
        reader.close()
    return {"topic": imu, "time_s": t, "temperature": temperature, "metadata": meta,
            "channels": [(name, sensor, axis, values[:, j].copy())
                         for j, (name, sensor, axis, _, _) in enumerate(wanted)]}
