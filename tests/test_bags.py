"""ROS bags in (issue 46, item 1): real bags written with rosbags' own writers — ROS 1 ``.bag``, ROS 2 ``.db3`` and
``.mcap`` — read as recordings, checked and exported with the same numbers as the same data from a CSV, and the
refusals: a wrong topic, a topic of another type, several IMU topics and none named, an empty bag, stamps that go
back, CSV flags on a bag."""
import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags")
from rosbags.rosbag1 import Writer as Writer1  # noqa: E402
from rosbags.rosbag2 import StoragePlugin  # noqa: E402
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from torchtea.cli import main  # noqa: E402
from torchtea.sensors.bags import bag_topics, is_bag, read_bag  # noqa: E402
from torchtea.sensors.io import InputError, read_recording, write_columns  # noqa: E402

KINDS = {"ros1": "imu.bag", "db3": "imu_db3", "mcap": "imu_mcap"}
T0_NS = 1_700_000_000_123_456_789
H_NS = 5_000_000  # 200 Hz


def write_bag(path, kind, t_ns, acc, gyr, temp=None, topic="/imu/data", extra_imu=None, temp_every=10):
    """A bag of ``kind`` (ros1, db3, mcap) with ``sensor_msgs/Imu`` on ``topic`` (header stamps ``t_ns``, the
    accelerometer ``acc`` and the gyroscope ``gyr``, (N, 3) each) and, given ``temp``, ``sensor_msgs/Temperature``
    on ``/imu/temperature`` every ``temp_every`` messages; ``extra_imu``: a second Imu topic's name."""
    ros1 = kind == "ros1"
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    T = ts.types
    Imu, Header, Time = T["sensor_msgs/msg/Imu"], T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    Q, V, Temp = T["geometry_msgs/msg/Quaternion"], T["geometry_msgs/msg/Vector3"], T["sensor_msgs/msg/Temperature"]
    ser = ts.serialize_ros1 if ros1 else ts.serialize_cdr
    plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
    writer = Writer1(path) if ros1 else Writer2(path, version=9, storage_plugin=plugin)
    z9 = np.zeros(9)

    def header(k, t):
        st = Time(sec=int(t // 1_000_000_000), nanosec=int(t % 1_000_000_000))
        return Header(seq=k, stamp=st, frame_id="imu") if ros1 else Header(stamp=st, frame_id="imu")

    def imu(k, t):
        return Imu(header=header(k, t), orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=z9,
                   angular_velocity=V(x=gyr[k, 0], y=gyr[k, 1], z=gyr[k, 2]), angular_velocity_covariance=z9,
                   linear_acceleration=V(x=acc[k, 0], y=acc[k, 1], z=acc[k, 2]),
                   linear_acceleration_covariance=z9)

    with writer:
        c = writer.add_connection(topic, Imu.__msgtype__, typestore=ts)
        c2 = writer.add_connection(extra_imu, Imu.__msgtype__, typestore=ts) if extra_imu else None
        ct = writer.add_connection("/imu/temperature", Temp.__msgtype__, typestore=ts) if temp is not None else None
        for k, t in enumerate(t_ns):
            writer.write(c, T0_NS + k * H_NS, ser(imu(k, int(t)), Imu.__msgtype__))
            if c2 is not None:
                writer.write(c2, T0_NS + k * H_NS, ser(imu(k, int(t)), Imu.__msgtype__))
            if ct is not None and k % temp_every == 0:
                writer.write(ct, T0_NS + k * H_NS, ser(Temp(header=header(k, int(t)), temperature=float(temp[k]),
                                                            variance=0.0), Temp.__msgtype__))
    return Path(path)


def _data(n=2000, seed=0):
    rng = np.random.default_rng(seed)
    acc = 0.02 * rng.standard_normal((n, 3)) + np.array([0.0, 0.0, 9.81])
    gyr = 1e-3 * rng.standard_normal((n, 3))
    gyr[:, 2] += 2e-5 * np.cumsum(rng.standard_normal(n))  # (a random walk on gz)
    temp = 25.0 + np.linspace(0.0, 2.0, n)
    t_ns = T0_NS + np.arange(n, dtype=np.int64) * H_NS
    return t_ns, acc, gyr, temp


@pytest.mark.parametrize("kind", list(KINDS))
def test_a_bag_reads_as_the_recording_it_holds(tmp_path, kind):
    """Every format: six channels in SI equal to what was written, the stamps in seconds from the first, the rate
    from them, the temperature topic interpolated onto the IMU's stamps (linear here, so exact)."""
    t_ns, acc, gyr, temp = _data()
    path = write_bag(tmp_path / KINDS[kind], kind, t_ns, acc, gyr, temp)
    assert is_bag(path)
    rec = read_recording(path)
    assert [c.label for c in rec.channels] == ["ax", "ay", "az", "gx", "gy", "gz"]
    assert np.array_equal(rec.accel_ms2(), acc)
    assert np.array_equal(np.column_stack([c.values for c in rec.sensor("gyroscope")]), gyr)
    assert rec.rate_hz == pytest.approx(200.0, rel=1e-12)
    assert rec.time_s[0] == 0.0 and rec.time_s[-1] == pytest.approx((len(t_ns) - 1) * 0.005, abs=1e-12)
    last = (len(t_ns) - 1) // 10 * 10  # (the last temperature message: held after it for one interval)
    assert np.allclose(rec.temperature[:last + 1], temp[:last + 1], atol=1e-12)
    assert np.all(rec.temperature[last + 1:] == temp[last]) and np.isfinite(rec.temperature).all()
    assert rec.temperature_column == "/imu/temperature" and rec.metadata["topic"] == "/imu/data"
    assert ("/imu/data", "sensor_msgs/msg/Imu", len(t_ns)) in bag_topics(path)
    if kind == "mcap":  # (a ROS 2 storage file alone, without its folder's metadata.yaml)
        alone = next(path.glob("*.mcap"))
        assert np.array_equal(read_recording(alone).accel_ms2(), acc)


@pytest.mark.parametrize("kind", ["mcap", pytest.param("ros1", marks=pytest.mark.slow),
                                  pytest.param("db3", marks=pytest.mark.slow)])
def test_check_and_export_of_a_bag_give_the_numbers_of_the_same_data_from_a_csv(tmp_path, kind, capsys):
    """`check` and `export --format kalibr` on the bag and on a CSV of the same samples, stamps and temperature (the
    mcap in the quick suite; ROS 1 and db3, read by the same code after rosbags' reader, in the slow one):
    the same fitted values (to 1e-9 relative: the stamps' seconds are the same numbers written as text) and the same
    Kalibr file but for the source it names and its ``rostopic``: the bag's IMU topic, Kalibr's default for a CSV."""
    t_ns, acc, gyr, temp = _data(1500, seed=1)
    bag = write_bag(tmp_path / KINDS[kind], kind, t_ns, acc, gyr, temp, temp_every=1)
    t = (t_ns - t_ns[0]) * 1e-9
    csv = write_columns(tmp_path / "same.csv", {"t": t, "ax": acc[:, 0], "ay": acc[:, 1], "az": acc[:, 2],
                                                "gx": gyr[:, 0], "gy": gyr[:, 1], "gz": gyr[:, 2], "temp": temp})
    runs = {}
    six = "ms2,ms2,ms2,rad/s,rad/s,rad/s"
    for name, one, every in (("bag", [str(bag)], [str(bag)]),
                             ("csv", [str(csv), "--units", "rad/s", "--temperature", "temp"],
                              [str(csv), "--units", six, "--temperature", "temp"])):
        out = tmp_path / f"check_{name}"
        assert main(["check", *one, "--columns", "gz", "--model", "white+random-walk", "--no-plots",
                     "--out", str(out)]) == 0
        doc = json.loads((out / "check.json").read_text())
        temperature = next(d for d in doc["axes"]["gz"]["diagnostics"] if d["name"] == "temperature")
        assert temperature["passed"] is not None  # (the bag's own temperature topic is the input, as --temperature)
        ex = tmp_path / f"export_{name}"
        assert main(["export", *every, "--format", "kalibr", "--model", "white+random-walk", "--no-plots",
                     "--out", str(ex)]) == 0
        runs[name] = (doc["axes"]["gz"]["base"]["parameters"],
                      (ex / "imu.yaml").read_text().replace(str(bag), "SOURCE").replace(str(csv), "SOURCE"))
    capsys.readouterr()
    assert "rostopic: /imu/data\n" in runs["bag"][1] and "rostopic: /imu0\n" in runs["csv"][1]
    runs["bag"] = (runs["bag"][0], runs["bag"][1].replace("rostopic: /imu/data", "rostopic: /imu0"))
    a, b = runs["bag"][0], runs["csv"][0]
    assert a.keys() == b.keys()
    for k in a:
        assert a[k] == pytest.approx(b[k], rel=1e-9, abs=1e-300)
    assert runs["bag"][1] == runs["csv"][1]


def test_the_refusals_name_the_bag_the_topic_and_what_the_bag_has(tmp_path, capsys):
    """A wrong topic lists the bag's topics; a topic of another type says its type; two IMU topics and none named
    asks for --topic and lists them; an empty bag says so; stamps that go back name the message; CSV flags on a bag
    are refused — each one line on stderr, exit 2, nothing written."""
    t_ns, acc, gyr, temp = _data(300)
    two = write_bag(tmp_path / "two.bag", "ros1", t_ns, acc, gyr, temp, extra_imu="/imu/raw")
    back = t_ns.copy()
    back[100], back[101] = back[101], back[100]
    shuffled = write_bag(tmp_path / "back", "mcap", back, acc, gyr)
    empty = write_bag(tmp_path / "empty", "db3", t_ns[:0], acc, gyr)
    cases = [
        ([str(two), "--topic", "/imu/nope"], ["no topic '/imu/nope'", "/imu/data (sensor_msgs/Imu, 300 messages)"]),
        ([str(two), "--topic", "/imu/temperature"], ["is sensor_msgs/Temperature, not sensor_msgs/Imu"]),
        ([str(two)], ["2 sensor_msgs/Imu topics", "--topic", "/imu/raw"]),
        ([str(empty)], ["holds no messages"]),
        ([str(shuffled)], ["'/imu/data'", "go back at message 101"]),
        ([str(two), "--topic", "/imu/data", "--units", "g"], ["leave out --units"]),
        ([str(two), "--topic", "/imu/data", "--temperature", "/imu/raw"], ["is sensor_msgs/Imu, not "
                                                                           "sensor_msgs/Temperature"]),
    ]
    for args, words in cases:
        out = tmp_path / "never"
        assert main(["check", *args, "--model", "white", "--no-plots", "--out", str(out)]) == 2, args
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1, err
        for w in words:
            assert w in err, (w, err)
        assert not out.exists()
    with pytest.raises(InputError, match="--topic is for ROS bags"):
        read_recording(write_columns(tmp_path / "a.csv", {"t": np.arange(10) * 0.01, "ax": np.zeros(10)}),
                       units="ms2", topic="/imu/data")


def test_a_damaged_ros1_bag_reads_as_rosbags_reads_it(tmp_path, monkeypatch):
    """A ROS 1 bag read by its own index gives what rosbags gives on damaged files too: junk inside a chunk (the same
    values, ROS 1 has no checksums), a truncated file and a damaged index (the same one refusal, from rosbags: the
    own index steps aside)."""
    from torchtea.sensors import bags

    t_ns, acc, gyr, temp = _data(3000)
    good = write_bag(tmp_path / "good.bag", "ros1", t_ns, acc, gyr, temp).read_bytes()
    junk = bytearray(good)
    junk[200_000:200_050] = b"\x13" * 50
    index = bytearray(good)
    index[-300:-200] = bytes(100)
    for name, data in (("junk", bytes(junk)), ("truncated", good[:len(good) // 2]), ("index", bytes(index))):
        path = tmp_path / f"{name}.bag"
        path.write_bytes(data)
        results = []
        for own in (True, False):
            if not own:
                monkeypatch.setattr(bags, "ros1_index", lambda p, opener: None)
            try:
                d = read_bag(path)
                results.append([d["time_s"], d["temperature"], *(c[3] for c in d["channels"])])
            except InputError as e:
                results.append(str(e))
            monkeypatch.undo()
        a, b = results
        assert type(a) is type(b), (name, a, b)
        assert a == b if isinstance(a, str) else all(np.array_equal(x, y, equal_nan=True) for x, y in zip(a, b))
    assert isinstance(a, str) and "not a readable ROS bag" in a


def _varied_bag(path, kind, n=700, compression=None):
    """A bag of ``kind`` whose Imu messages carry frame ids of every length from 0 to 9 (CDR pads the float64 fields
    to 8 bytes after them, so their offsets move) and values that use every bit, beside a second Imu topic, a
    temperature topic and a string topic interleaved; ROS 1 chunks ``compression`` (BZ2, LZ4) if given."""
    from rosbags.rosbag1 import Writer as W1

    ros1 = kind == "ros1"
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    T = ts.types
    Imu, Header, Time = T["sensor_msgs/msg/Imu"], T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    Q, V, Temp, Str = (T["geometry_msgs/msg/Quaternion"], T["geometry_msgs/msg/Vector3"],
                       T["sensor_msgs/msg/Temperature"], T["std_msgs/msg/String"])
    ser = ts.serialize_ros1 if ros1 else ts.serialize_cdr
    writer = Writer1(path) if ros1 else Writer2(path, version=9, storage_plugin=(
        StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3))
    if compression is not None:
        writer.set_compression(getattr(W1.CompressionFormat, compression))
    rng = np.random.default_rng(3)
    vals = rng.standard_normal((n, 6)) * 10.0 ** rng.integers(-9, 4, (n, 6))
    z9 = rng.standard_normal(9)

    def header(k, frame):
        st = Time(sec=1_700_000_000 + k // 100, nanosec=(k % 100) * 10_000_000 + 7)
        return Header(seq=k, stamp=st, frame_id=frame) if ros1 else Header(stamp=st, frame_id=frame)

    with writer:
        c = writer.add_connection("/imu/data", Imu.__msgtype__, typestore=ts)
        c2 = writer.add_connection("/imu/raw", Imu.__msgtype__, typestore=ts)
        ct = writer.add_connection("/imu/temperature", Temp.__msgtype__, typestore=ts)
        cs = writer.add_connection("/log", Str.__msgtype__, typestore=ts)
        for k in range(n):
            frame = "imu_link9"[:k % 10]
            msg = Imu(header=header(k, frame), orientation=Q(x=0.1, y=0.2, z=0.3, w=0.9), orientation_covariance=z9,
                      angular_velocity=V(x=vals[k, 3], y=vals[k, 4], z=vals[k, 5]), angular_velocity_covariance=z9,
                      linear_acceleration=V(x=vals[k, 0], y=vals[k, 1], z=vals[k, 2]),
                      linear_acceleration_covariance=z9)
            writer.write(c, 1_000 + 10 * k, ser(msg, Imu.__msgtype__))
            if k % 3 == 0:
                writer.write(c2, 1_000 + 10 * k, ser(msg, Imu.__msgtype__))
            if k % 7 == 0:
                writer.write(ct, 1_001 + 10 * k, ser(Temp(header=header(k, "temp_frame"[:k % 11]), temperature=25.0 + k / n,
                                                          variance=0.0), Temp.__msgtype__))
                writer.write(cs, 1_002 + 10 * k, ser(Str(data="x" * (k % 13)), Str.__msgtype__))
    return Path(path)


@pytest.mark.parametrize("kind,compression", [("ros1", None), ("ros1", "BZ2"), ("ros1", "LZ4"), ("db3", None),
                                              ("mcap", None)])
def test_the_array_decoder_is_the_generic_reader(tmp_path, kind, compression, monkeypatch):
    """``sensor_msgs/Imu`` and ``sensor_msgs/Temperature`` decoded at array speed (``bag_arrays``) against rosbags'
    generic reader, message by message, on every format: the same header stamps, receive times and fields, bit for
    bit, with frame ids of every length and other topics interleaved; and ``read_bag`` gives the same recording
    either way."""
    from torchtea.sensors import bags
    from torchtea.sensors.bag_arrays import imu_arrays, temperature_arrays
    from torchtea.sensors.bags import IMU_FIELDS, _reader, read_bag

    path = _varied_bag(tmp_path / (KINDS[kind] if compression is None else f"{compression}.bag"), kind,
                       compression=compression)
    reader = _reader(path)
    try:
        conns = [c for c in reader.connections if c.topic == "/imu/data"]
        fast = imu_arrays(reader, conns)
        assert fast is not None, "no array path"
        stamps, received, values = [], [], []
        for conn, t_ns, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            stamps.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
            received.append(t_ns)
            values.append([getattr(getattr(msg, fld), comp) for _, _, _, fld, comp in IMU_FIELDS])
    finally:
        reader.close()
    assert np.array_equal(fast[0], stamps) and np.array_equal(fast[1], received)
    assert np.array_equal(fast[2], np.array(values))
    reader = _reader(path)
    try:  # the temperature topic's the same way
        conns = [c for c in reader.connections if c.topic == "/imu/temperature"]
        fast = temperature_arrays(reader, conns)
        assert fast is not None, "no array path for the temperature"
        slow = [(reader.deserialize(raw, conn.msgtype), t_ns) for conn, t_ns, raw in reader.messages(connections=conns)]
    finally:
        reader.close()
    assert np.array_equal(fast[0], [m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec for m, _ in slow])
    assert np.array_equal(fast[1], [t for _, t in slow])
    assert np.array_equal(fast[2][:, 0], [m.temperature for m, _ in slow])
    if kind == "ros1":  # the bag's own index read without rosbags: its topics and both decoders the same
        from torchtea.sensors.bag_ros1 import ros1_index

        index, reader = ros1_index(path, _reader), _reader(path)
        assert index is not None, "the ROS 1 index was not read"
        try:
            assert bags._topics(index) == bags._topics(reader)
            for topic, decode in (("/imu/data", imu_arrays), ("/imu/temperature", temperature_arrays)):
                own = decode(index, [c for c in index.connections if c.topic == topic])
                theirs = decode(reader, [c for c in reader.connections if c.topic == topic])
                assert own is not None and all(np.array_equal(x, y) for x, y in zip(own, theirs))
        finally:
            index.close()
            reader.close()
    a = read_bag(path, topic="/imu/data", columns=["gz", "ax"])
    monkeypatch.setattr(bags, "imu_arrays", lambda reader, conns: None)
    monkeypatch.setattr(bags, "temperature_arrays", lambda reader, conns: None)
    b = read_bag(path, topic="/imu/data", columns=["gz", "ax"])
    assert np.array_equal(a["time_s"], b["time_s"]) and np.array_equal(a["temperature"], b["temperature"])
    assert [c[:3] for c in a["channels"]] == [c[:3] for c in b["channels"]]
    assert all(np.array_equal(x[3], y[3]) for x, y in zip(a["channels"], b["channels"]))
