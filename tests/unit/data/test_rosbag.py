"""Tests of the ROS bag reader (``data.format: rosbag``).

Every bag is written here with rosbags' writers from a simulated log whose content the test knows;
the expected arrays are computed from that log independently of the reader (brute-force
interpolation, float32-rounded ranges and angles as the messages hold them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from decimal import Decimal
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin, Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from nanoslam_jax.data import LogFormatError
from nanoslam_jax.data._rosbag import load_rosbag

KINDS = ("ros1", "sqlite3", "mcap")
T0 = 1_700_000_000  # s: UNIX-time stamps, as real bags have
RANGE_MIN, RANGE_MAX = 0.1, 25.0
BEAMS = 181
# the reader's notes on the simulated log (asserted where they matter)
pytestmark = [
    pytest.mark.filterwarnings("ignore:.*dropped \\d+ scans:UserWarning"),
    pytest.mark.filterwarnings("ignore:.*scans were stamped earlier:UserWarning"),
]


@dataclass
class Sim:
    """A simulated log: scans and odometry in bag order, with stamps in ns."""

    scan_ns: list[int]
    ranges: np.ndarray  # (S, B) float32, as the messages carry them
    odom_ns: list[int]
    odom: np.ndarray  # (N, 3) x, y, yaw
    angle_min: float = -math.pi / 2
    angle_increment: float = math.pi / 180
    range_max: list[float] = field(default_factory=list)  # per scan; empty: RANGE_MAX
    beams: list[int] = field(default_factory=list)  # per scan; empty: all BEAMS
    scan_frame: str = "laser"
    base_frame: str = "base_link"
    # (parent, child, x, y, z, yaw) static transforms, in messages of two each
    tf: list[tuple[str, str, float, float, float, float]] = field(default_factory=list)


#: The mounting chain: base_footprint -> base_link, base_footprint -> laser_mount -> laser.
TF_CHAIN = [
    ("base_footprint", "base_link", -0.1, 0.02, 0.1, 0.05),
    ("base_footprint", "laser_mount", 0.2, 0.05, 0.3, 0.1),
    ("laser_mount", "laser", 0.05, 0.0, 0.0, 0.2),
]


def _tf_mount():
    """The laser in base_link, composed by hand from TF_CHAIN (planar: only yaw rotations)."""
    lx, ly = 0.2 + 0.05 * math.cos(0.1), 0.05 + 0.05 * math.sin(0.1)  # the laser in base_footprint, yaw 0.3
    dx, dy = lx + 0.1, ly - 0.02
    c, s = math.cos(0.05), math.sin(0.05)
    return (c * dx + s * dy, -s * dx + c * dy, 0.3 - 0.05)


TF_MOUNT = _tf_mount()


def simulate(n_scans: int = 30, seed: int = 0) -> Sim:
    """Scans at 10 Hz with jittered stamps, two of them out of order, two before the odometry
    starts and one after it ends; odometry at 20 Hz on a path whose yaw crosses +-pi, several
    times between the two odometry messages around a scan."""
    rng = np.random.default_rng(seed)
    scan_ns = [(T0 + 1) * 10**9 + k * 100_000_000 + int(rng.integers(0, 1000)) * 1000 for k in range(n_scans)]
    scan_ns[10], scan_ns[11] = scan_ns[11], scan_ns[10]  # out of order in the bag
    scan_ns[20], scan_ns[21] = scan_ns[21], scan_ns[20]
    first, last = min(scan_ns[2:]), scan_ns[-2]
    odom_ns = list(range(first - 30_000_000, last + 20_000_000, 50_000_000))
    odom_ns = [t for t in odom_ns if t <= last] + [last]
    assert odom_ns[0] > sorted(scan_ns)[1] and odom_ns[0] <= sorted(scan_ns)[2]
    s = (np.array(odom_ns) - odom_ns[0]) / 1e9
    odom = np.column_stack([2.0 + 0.5 * s, -1.0 + 0.2 * s**2, math.pi + 0.6 * np.sin(12.0 * s)])
    odom[:, 2] = np.arctan2(np.sin(odom[:, 2]), np.cos(odom[:, 2]))
    ranges = rng.uniform(0.5, 20.0, (n_scans, BEAMS)).astype(np.float32)
    ranges[:, ::17] = np.inf
    ranges[:, 3::19] = np.nan
    ranges[:, 5::23] = 0.05  # below range_min
    ranges[:, 7::29] = 30.0  # beyond range_max
    ranges[:, 9::31] = RANGE_MAX  # at range_max: no return
    ranges[:, 11::37] = RANGE_MIN  # at range_min: a return
    return Sim(scan_ns, ranges, odom_ns, odom, tf=list(TF_CHAIN))


# ----------------------------------------------------------------------------- writing bags


def _store(kind: str):
    if kind == "ros1":
        store = get_typestore(Stores.ROS1_NOETIC)
        store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))
        return store
    return get_typestore(Stores.ROS2_HUMBLE)


def _messages(sim: Sim, store, ros1: bool):
    """(topic, type, record time ns, message) in bag order."""
    T = store.types
    slash = "/" if ros1 else ""  # ROS 1 logs often write frame ids with a leading slash

    def header(ns: int, frame: str):
        stamp = T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
        kw = {"seq": 0} if ros1 else {}
        return T["std_msgs/msg/Header"](**kw, stamp=stamp, frame_id=slash + frame if frame else "")

    def quat(yaw: float):
        return T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))

    vec = T["geometry_msgs/msg/Vector3"]
    out = []
    for k in range(0, len(sim.tf), 2):
        tfs = [
            T["geometry_msgs/msg/TransformStamped"](
                header=header(T0 * 10**9, parent),
                child_frame_id=slash + child,
                transform=T["geometry_msgs/msg/Transform"](translation=vec(x=x, y=y, z=z), rotation=quat(yaw)),
            )
            for parent, child, x, y, z, yaw in sim.tf[k : k + 2]
        ]
        out.append(("/tf_static", "tf2_msgs/msg/TFMessage", 1, T["tf2_msgs/msg/TFMessage"](transforms=tfs)))
    for i, ns in enumerate(sim.scan_ns):
        n = sim.beams[i] if sim.beams else sim.ranges.shape[1]
        msg = T["sensor_msgs/msg/LaserScan"](
            header=header(ns, sim.scan_frame),
            angle_min=sim.angle_min,
            angle_max=sim.angle_min + (n - 1) * sim.angle_increment,
            angle_increment=sim.angle_increment,
            time_increment=0.0,
            scan_time=0.1,
            range_min=RANGE_MIN,
            range_max=sim.range_max[i] if sim.range_max else RANGE_MAX,
            ranges=np.resize(sim.ranges[i], n).astype(np.float32),
            intensities=np.zeros(0, dtype=np.float32),
        )
        out.append(("/scan", "sensor_msgs/msg/LaserScan", T0 * 10**9 + 2 * i + 2, msg))
    for i, (ns, (x, y, yaw)) in enumerate(zip(sim.odom_ns, sim.odom)):
        pose = T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=x, y=y, z=0.0), orientation=quat(yaw)
        )
        twist = T["geometry_msgs/msg/Twist"](linear=vec(x=0.0, y=0.0, z=0.0), angular=vec(x=0.0, y=0.0, z=0.0))
        msg = T["nav_msgs/msg/Odometry"](
            header=header(ns, "odom"),
            child_frame_id=slash + sim.base_frame,
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)),
        )
        out.append(("/odom", "nav_msgs/msg/Odometry", T0 * 10**9 + 2 * i + 3, msg))
    return sorted(out, key=lambda m: m[2])


def write_bag(directory: Path, sim: Sim, kind: str, topics=("/tf_static", "/scan", "/odom")) -> Path:
    """Write ``sim`` as a bag of ``kind`` ('ros1', 'sqlite3', 'mcap') under ``directory``; only the
    messages of ``topics`` (a topic in ``topics`` gets its connection even without messages)."""
    store = _store(kind)
    msgs = [m for m in _messages(sim, store, kind == "ros1") if m[0] in topics]
    types = {
        "/tf_static": "tf2_msgs/msg/TFMessage",
        "/scan": "sensor_msgs/msg/LaserScan",
        "/odom": "nav_msgs/msg/Odometry",
    }
    if kind == "ros1":
        path = directory / "log.bag"
        writer: Writer1 | Writer2 = Writer1(path)
        serialize = store.serialize_ros1
    else:
        path = directory / f"log_{kind}"
        plugin = StoragePlugin.SQLITE3 if kind == "sqlite3" else StoragePlugin.MCAP
        writer = Writer2(path, version=9, storage_plugin=plugin)
        serialize = store.serialize_cdr
    with writer:
        conns = {t: writer.add_connection(t, types[t], typestore=store) for t in topics if t in types}
        for topic, typ, ns, msg in msgs:
            writer.write(conns[topic], ns, serialize(msg, typ))
    return path


# ----------------------------------------------------------------------------- the expected log


def _seconds(ns: int) -> float:
    return float(Decimal(ns // 10**9) + Decimal(ns % 10**9) / Decimal(10**9))


def expected(sim: Sim):
    """(time, ranges, angles, odom, max_range) the reader must return, computed from ``sim``."""
    f32 = lambda v: float(np.float32(v))  # noqa: E731  the messages' float32 fields
    max_range = f32(RANGE_MAX)
    order = sorted(range(len(sim.scan_ns)), key=lambda i: (sim.scan_ns[i], i))
    keep = [i for i in order if sim.odom_ns[0] <= sim.scan_ns[i] <= sim.odom_ns[-1]]
    r = sim.ranges[keep].astype(np.float64)
    ok = np.isfinite(r) & (r >= f32(RANGE_MIN)) & (r < max_range)
    ranges = np.where(ok, r, max_range)
    angles = np.array([f32(sim.angle_min) + b * f32(sim.angle_increment) for b in range(sim.ranges.shape[1])])
    odom = []
    for i in keep:
        t = sim.scan_ns[i]
        j = max(j for j in range(len(sim.odom_ns)) if sim.odom_ns[j] <= t)
        if j == len(sim.odom_ns) - 1:
            odom.append(sim.odom[j])
            continue
        w = (t - sim.odom_ns[j]) / (sim.odom_ns[j + 1] - sim.odom_ns[j])
        a, b = sim.odom[j], sim.odom[j + 1]
        d = math.atan2(math.sin(b[2] - a[2]), math.cos(b[2] - a[2]))
        yaw = a[2] + w * d
        odom.append([a[0] + w * (b[0] - a[0]), a[1] + w * (b[1] - a[1]), math.atan2(math.sin(yaw), math.cos(yaw))])
    time = np.array([_seconds(sim.scan_ns[i]) for i in keep])
    return time, ranges, angles, np.array(odom), max_range


def _assert_log(log, sim: Sim, mount=TF_MOUNT):
    time, ranges, angles, odom, max_range = expected(sim)
    np.testing.assert_array_equal(log.scans.time, time)
    np.testing.assert_array_equal(log.scans.ranges, ranges)
    np.testing.assert_allclose(log.scans.angles, angles, rtol=0, atol=1e-12)
    assert log.scans.max_range == max_range
    dyaw = np.arctan2(np.sin(log.odom[:, 2] - odom[:, 2]), np.cos(log.odom[:, 2] - odom[:, 2]))
    np.testing.assert_allclose(log.odom[:, :2], odom[:, :2], rtol=0, atol=1e-9)
    np.testing.assert_allclose(dyaw, 0.0, atol=1e-9)
    assert np.all(np.abs(log.odom[:, 2]) <= np.pi)
    np.testing.assert_allclose(log.laser_pose, mount, rtol=0, atol=1e-9)


# ----------------------------------------------------------------------------- reading


@pytest.mark.parametrize("kind", KINDS)
def test_reads_each_bag_kind_to_the_expected_log(tmp_path, kind):
    sim = simulate()
    path = write_bag(tmp_path, sim, kind)
    with pytest.warns(UserWarning) as record:
        log = load_rosbag(path)
    text = " ".join(str(w.message) for w in record)
    assert "dropped 2 scans" in text and "and 1 after the last" in text
    assert "2 scans were stamped earlier" in text
    assert log.n_scans == 30 - 3
    assert log.out_of_order == 2
    assert log.source == str(path)
    _assert_log(log, sim)
    # the simulated readings: every kind of no return is there, and the reader kept the others
    assert (~log.scans.valid).sum() == (~np.isfinite(expected(sim)[1]) | (expected(sim)[1] >= RANGE_MAX)).sum()
    assert log.scans.valid[:, 11].all()  # exactly range_min is a return
    # the yaw interpolation was tested across +-pi: scans between odometry poses either side of it
    t, ts = [int(round((v - T0) * 1e6)) for v in log.scans.time], [(v // 1000) - T0 * 10**6 for v in sim.odom_ns]
    k = np.searchsorted(ts, t, side="right") - 1
    k = np.clip(k, 0, len(ts) - 2)
    across = np.abs(sim.odom[k + 1, 2] - sim.odom[k, 2]) > np.pi
    assert across.sum() >= 2


def test_all_three_kinds_read_the_same(tmp_path):
    sim = simulate(seed=3)
    logs = []
    for kind in KINDS:
        (tmp_path / kind).mkdir()
        with pytest.warns(UserWarning):
            logs.append(load_rosbag(write_bag(tmp_path / kind, sim, kind)))
    for log in logs[1:]:
        np.testing.assert_array_equal(log.scans.ranges, logs[0].scans.ranges)
        np.testing.assert_array_equal(log.scans.time, logs[0].scans.time)
        np.testing.assert_array_equal(log.odom, logs[0].odom)


def test_negative_increment_reverses_the_beams(tmp_path):
    sim = simulate()
    sim = replace(sim, angle_min=math.pi / 2, angle_increment=-math.pi / 180)
    with pytest.warns(UserWarning):
        log = load_rosbag(write_bag(tmp_path, sim, "sqlite3"))
    _, ranges, angles, _, _ = expected(sim)
    np.testing.assert_allclose(log.scans.angles, angles[::-1], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(log.scans.ranges, ranges[:, ::-1])
    assert np.all(np.diff(log.scans.angles) > 0)
    assert log.scans.angles[0] < 0 < log.scans.angles[-1]


def test_mounting_from_the_argument_then_zero(tmp_path):
    sim = replace(simulate(), tf=[])
    path = write_bag(tmp_path, sim, "mcap", topics=("/scan", "/odom"))
    log = load_rosbag(path, laser_pose=[0.3, -0.1, 3 * math.pi])
    np.testing.assert_allclose(log.laser_pose, [0.3, -0.1, math.pi], atol=1e-12)
    with pytest.warns(UserWarning, match="no /tf_static; the laser's mounting is taken as zero"):
        log = load_rosbag(path)
    np.testing.assert_array_equal(log.laser_pose, [0.0, 0.0, 0.0])
    _assert_log(log, sim, mount=(0.0, 0.0, 0.0))


def test_tf_static_wins_over_the_argument_and_other_topic_names(tmp_path):
    sim = simulate()
    path = write_bag(tmp_path, sim, "sqlite3")
    with pytest.warns(UserWarning, match=r"laser_pose \[1.0, 2.0, 0.0\] ignored"):
        log = load_rosbag(path, laser_pose=(1.0, 2.0, 0.0))
    np.testing.assert_allclose(log.laser_pose, TF_MOUNT, atol=1e-9)
    # a chain that does not reach the scans' frame: the argument
    other = replace(sim, scan_frame="front_laser")
    (tmp_path / "b").mkdir()
    with pytest.warns(UserWarning, match="dropped"):
        log = load_rosbag(write_bag(tmp_path / "b", other, "sqlite3"), laser_pose=(1.0, 2.0, 0.0))
    np.testing.assert_array_equal(log.laser_pose, [1.0, 2.0, 0.0])


def test_topic_names_are_arguments(tmp_path):
    sim = simulate()
    path = write_bag(tmp_path, sim, "sqlite3")
    with pytest.raises(LogFormatError, match="no topic '/base_scan'") as e:
        load_rosbag(path, scan_topic="/base_scan")
    assert "set data.scan_topic" in str(e.value)


# ----------------------------------------------------------------------------- bad input


def test_missing_topics_name_the_bag_topics(tmp_path):
    path = write_bag(tmp_path, simulate(), "ros1", topics=("/scan",))
    with pytest.raises(LogFormatError) as e:
        load_rosbag(path)
    msg = str(e.value)
    assert str(path) in msg and "no topic '/odom' (nav_msgs/msg/Odometry; set data.odom_topic)" in msg
    assert "the bag has /scan (sensor_msgs/msg/LaserScan)" in msg
    (tmp_path / "b").mkdir()
    path = write_bag(tmp_path / "b", simulate(), "mcap", topics=("/odom", "/tf_static"))
    with pytest.raises(LogFormatError, match="no topic '/scan'") as e:
        load_rosbag(path)
    assert "/odom (nav_msgs/msg/Odometry), /tf_static (tf2_msgs/msg/TFMessage)" in str(e.value)


def test_a_topic_of_the_wrong_type(tmp_path):
    path = write_bag(tmp_path, simulate(), "sqlite3")
    with pytest.raises(LogFormatError, match="topic '/scan' holds sensor_msgs/msg/LaserScan, expected nav_msgs"):
        load_rosbag(path, odom_topic="/scan")


@pytest.mark.parametrize("topic", ["/scan", "/odom"])
def test_a_topic_without_messages(tmp_path, topic):
    sim = simulate()
    sim = replace(sim, scan_ns=[]) if topic == "/scan" else replace(sim, odom_ns=[], odom=np.zeros((0, 3)))
    path = write_bag(tmp_path, sim, "sqlite3")
    with pytest.raises(LogFormatError, match=f"{path}: topic {topic} has no messages"):
        load_rosbag(path)


def test_beam_count_change_names_the_message(tmp_path):
    sim = simulate()
    sim.beams = [BEAMS] * 7 + [BEAMS - 1] + [BEAMS] * 22
    path = write_bag(tmp_path, sim, "mcap")
    stamp = _seconds(sim.scan_ns[7])
    with pytest.raises(LogFormatError) as e:
        load_rosbag(path)
    msg = str(e.value)
    assert f"{path} topic /scan message 8 (stamp {stamp!r} s)" in msg
    assert "expected the first message's 181 beams" in msg and "got 180 beams" in msg


def test_angle_change_names_the_message(tmp_path):
    sim = simulate()
    # a bag whose 5th scan has another increment: write it message by message
    store = _store("ros1")
    msgs = _messages(sim, store, True)
    scans = [m for m in msgs if m[0] == "/scan"]
    bad = scans[4][3]
    bad.angle_increment = math.pi / 360
    path = tmp_path / "angles.bag"
    with Writer1(path) as w:
        conns = {}
        for topic, typ, ns, m in msgs:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, typ, typestore=store)
            w.write(conns[topic], ns, store.serialize_ros1(m, typ))
    with pytest.raises(LogFormatError, match=r"topic /scan message 5 \(stamp 1700000001\.4\d+ s\): the scan settings"):
        load_rosbag(path)


def test_zero_angle_increment(tmp_path):
    path = write_bag(tmp_path, replace(simulate(), angle_increment=0.0), "sqlite3")
    with pytest.raises(
        LogFormatError, match=r"topic /scan message 1 \(stamp [\d.]+ s\): angle_increment is 0 with 181"
    ):
        load_rosbag(path)


def test_odometry_back_in_time_names_the_message(tmp_path):
    sim = simulate()
    sim.odom_ns[12] = sim.odom_ns[10]
    path = write_bag(tmp_path, sim, "sqlite3")
    with pytest.raises(LogFormatError, match=r"topic /odom message 13 \(stamp [\d.]+ s\): the odometry jumps back"):
        load_rosbag(path)


def test_no_scan_within_the_odometry(tmp_path):
    sim = simulate()
    sim = replace(sim, odom_ns=[t + 10**11 for t in sim.odom_ns])
    path = write_bag(tmp_path, sim, "sqlite3")
    with pytest.raises(LogFormatError, match="no scan on /scan lies within the odometry's time span"):
        load_rosbag(path)


def test_not_a_bag(tmp_path):
    (tmp_path / "x.bag").write_bytes(b"not a bag at all\n")
    with pytest.raises(LogFormatError, match=r"x\.bag: not a readable ROS bag"):
        load_rosbag(tmp_path / "x.bag")
    with pytest.raises(LogFormatError, match="not a ROS 2 bag directory"):
        load_rosbag(tmp_path)
    with pytest.raises(FileNotFoundError, match="ROS bag not found"):
        load_rosbag(tmp_path / "missing.bag")
    with pytest.raises(ValueError, match="laser_pose: expected three finite numbers"):
        load_rosbag(tmp_path / "x.bag", laser_pose=[0.0, 0.0])


# ----------------------------------------------------------------------------- CARMEN equivalence


def _room_ranges(poses: np.ndarray, angle_min: float, angle_increment: float) -> np.ndarray:
    """Ranges of BEAMS beams from each laser pose inside the room |x| <= 5, |y| <= 4, ray-cast here."""
    a = poses[:, 2:3] + angle_min + angle_increment * np.arange(BEAMS)
    c, s = np.cos(a), np.sin(a)
    with np.errstate(divide="ignore", invalid="ignore"):
        hits = [
            np.where(c > 1e-12, (5 - poses[:, :1]) / c, np.inf),
            np.where(c < -1e-12, (-5 - poses[:, :1]) / c, np.inf),
            np.where(s > 1e-12, (4 - poses[:, 1:2]) / s, np.inf),
            np.where(s < -1e-12, (-4 - poses[:, 1:2]) / s, np.inf),
        ]
    return np.min(hits, axis=0)


def _equivalent_logs(tmp_path: Path, kind: str) -> tuple[Path, Path]:
    """The same drive through a rectangular room written as a bag of ``kind`` and as a CARMEN file
    (odometry at every scan, as FLASER lines carry it; 81.91 for no return)."""
    sim = replace(simulate(n_scans=40, seed=5), tf=[])
    sim.scan_ns.sort()
    sim.odom_ns = list(sim.scan_ns)
    s = (np.array(sim.odom_ns) - sim.odom_ns[0]) / 1e9
    sim.odom = np.column_stack(
        [-2.0 + 0.8 * s, -1.0 + 0.3 * s, np.arctan2(np.sin(0.4 + 0.1 * s), np.cos(0.4 + 0.1 * s))]
    )
    r = _room_ranges(sim.odom, sim.angle_min, sim.angle_increment)
    r[:, 5::23] = np.nan  # a few no returns
    no_return = 81.91
    sim.range_max = [no_return] * len(sim.scan_ns)
    r[~np.isfinite(r) | (r < RANGE_MIN) | (r >= RANGE_MAX)] = no_return
    sim.ranges = r.astype(np.float32)
    bag = write_bag(tmp_path, sim, kind, topics=("/scan", "/odom"))
    lines = []
    for ns, ranges, (x, y, th) in zip(sim.scan_ns, sim.ranges, sim.odom):
        t = f"{ns // 10**9}.{ns % 10**9:09d}"
        values = " ".join(repr(float(v)) if v < RANGE_MAX else "81.91" for v in ranges)
        pose = " ".join(repr(float(v)) for v in (x, y, th))
        lines.append(f"FLASER {BEAMS} {values} {pose} {pose} {t} host {t}")
    clf = tmp_path / "log.clf"
    clf.write_text("# written by the test\n" + "\n".join(lines) + "\n")
    return bag, clf


@pytest.mark.parametrize("kind", KINDS)
def test_a_bag_and_the_equivalent_carmen_file_give_the_same_log(tmp_path, kind):
    from nanoslam_jax.data._carmen import load_carmen

    bag_path, clf = _equivalent_logs(tmp_path, kind)
    with pytest.warns(UserWarning, match="mounting is taken as zero"):
        bag = load_rosbag(bag_path)
    carmen = load_carmen(clf)
    assert carmen.n_scans == bag.n_scans == 40
    np.testing.assert_array_equal(carmen.scans.time, bag.scans.time)
    np.testing.assert_array_equal(carmen.scans.valid, bag.scans.valid)
    np.testing.assert_array_equal(carmen.scans.ranges[bag.scans.valid], bag.scans.ranges[bag.scans.valid])
    # the bag's angles are float32 (angle_min, angle_increment): equal to 2e-7 rad
    np.testing.assert_allclose(carmen.scans.angles, bag.scans.angles, rtol=0, atol=1e-6)
    np.testing.assert_allclose(carmen.odom, bag.odom, rtol=0, atol=1e-9)
    np.testing.assert_allclose(carmen.laser_pose, bag.laser_pose, rtol=0, atol=1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_a_bag_and_the_equivalent_carmen_file_give_the_same_trajectory(tmp_path, kind):
    """EKF-SLAM on the room's walls, from the bag and from the CARMEN file: the same path to the
    bag's float32 beam angles (largest difference below 1e-4 m and 1e-5 rad)."""
    import warnings

    from nanoslam_jax.app.config import load_config
    from nanoslam_jax.app.experiment import load_log
    from nanoslam_jax.app.filters import settings_from_config
    from nanoslam_jax.methods import run_filter

    bag_path, clf = _equivalent_logs(tmp_path, kind)
    common = [
        "data.detections=laser_lines",
        "model.motion=unicycle",
        "model.measurement=line",
        "data.max_range=25",
        "detector.max_range=25",
        "filter.method=ekf_slam",
        "filter.capacity=16",
        "filter.window=8",
        "data.k_max=8",
    ]
    paths = {}
    for name, sets, path in (
        ("bag", ["data.kind=victoria_park", "data.format=rosbag"], bag_path),
        ("carmen", ["data.kind=victoria_park", "data.format=carmen"], clf),
    ):
        cfg = load_config(None, common + sets)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # the bag's mounting taken as zero
            log = load_log(cfg, str(path))
        static, params = settings_from_config(cfg, log.segments.k_max)
        run = run_filter(static, params, log.segments, 0)
        paths[name] = np.asarray(static.estimate.trajectory(run.outputs, run.state))
        assert int(np.asarray(run.state.landmark_map().active).sum()) >= 2  # walls were mapped
    bag_est, carmen_est = paths["bag"], paths["carmen"]
    assert bag_est.shape == carmen_est.shape and np.all(np.isfinite(bag_est))
    assert np.max(np.abs(bag_est[:, :2] - carmen_est[:, :2])) < 1e-4
    assert np.max(np.abs(np.angle(np.exp(1j * (bag_est[:, 2] - carmen_est[:, 2]))))) < 1e-5


# ----------------------------------------------------------------------------- config and load_log

BAG_CONFIG = {"data": {"format": "rosbag", "detections": "laser_lines"}, "model": {"measurement": "line"}}


def _config(**data):
    from nanoslam_jax.app.config import config_from_dict

    return config_from_dict({**BAG_CONFIG, "data": {**BAG_CONFIG["data"], **data}})


def test_config_keys():
    from nanoslam_jax.app.config import ConfigError, apply_overrides, config_from_dict

    cfg = _config(scan_topic="/base_scan", odom_topic="/wheel_odom", laser_pose=[0.1, -0.2, 3])
    assert (cfg.data.scan_topic, cfg.data.odom_topic) == ("/base_scan", "/wheel_odom")
    assert cfg.data.laser_pose == (0.1, -0.2, 3.0)
    assert _config().data.laser_pose is None
    raw = apply_overrides(BAG_CONFIG, ["data.laser_pose=[0.5, 0, 0.25]"])
    assert config_from_dict(raw).data.laser_pose == (0.5, 0.0, 0.25)
    with pytest.raises(ConfigError, match=r"key 'data.laser_pose': expected a list of 3 numbers, got \[0.1, 0.2\]"):
        _config(laser_pose=[0.1, 0.2])
    with pytest.raises(ConfigError, match=r"key 'data.laser_pose\[2\]': expected a number"):
        _config(laser_pose=[0.1, 0.2, "x"])
    with pytest.raises(ConfigError, match="key 'data.detections': a ROS bag holds laser scans, not detections"):
        _config(detections="file")


def test_the_bag_path(tmp_path):
    from nanoslam_jax.app.config import resolve_data_dir

    (tmp_path / "log.bag").write_bytes(b"")
    assert resolve_data_dir(_config(), str(tmp_path / "log.bag")) == tmp_path / "log.bag"
    assert resolve_data_dir(_config(path=str(tmp_path)), None) == tmp_path
    with pytest.raises(FileNotFoundError, match=r"other\.bag \(from --data\): ROS bag not found"):
        resolve_data_dir(_config(), str(tmp_path / "other.bag"))
    with pytest.raises(FileNotFoundError, match="data.format rosbag: give the bag with --data BAG"):
        resolve_data_dir(_config(), None)


def test_load_log_passes_the_keys_to_load_rosbag(tmp_path, monkeypatch):
    from nanoslam_jax.data import _laser_log, _rosbag
    from nanoslam_jax.app.experiment import load_log

    class Reached(Exception):
        pass

    def fake_load(path, **kwargs):
        raise Reached(path, kwargs)

    monkeypatch.setattr(_rosbag, "load_rosbag", fake_load)
    # laser_odom_raw is not reached; before the CARMEN reader's merge it is not there to import
    monkeypatch.setattr(_laser_log, "laser_odom_raw", lambda log: pytest.fail("not reached"), raising=False)
    (tmp_path / "log.bag").write_bytes(b"")
    cfg = _config(scan_topic="/s", odom_topic="/o", laser_pose=[1, 2, 0.5])
    with pytest.raises(Reached) as e:
        load_log(cfg, str(tmp_path / "log.bag"))
    assert e.value.args == (
        tmp_path / "log.bag",
        {"scan_topic": "/s", "odom_topic": "/o", "laser_pose": (1.0, 2.0, 0.5)},
    )
