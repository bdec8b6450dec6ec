"""Reading a robot's 2-D laser log from a ROS bag: ROS 1 ``.bag`` files and ROS 2 bag directories
(sqlite3 or mcap storage), through the pure-Python ``rosbags`` library.

The bag must hold ``sensor_msgs/msg/LaserScan`` messages on one topic and ``nav_msgs/msg/Odometry``
on another. The odometry pose is interpolated to each scan's ``header.stamp``; the laser's mounting
on the robot comes from ``/tf_static`` when the bag has it (docs/data.md, section "ROS bags").
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any, Optional

import numpy as np

from nanoslam_jax.lib._angles import wrap_angle_np
from nanoslam_jax.data._laser import LaserScans
from nanoslam_jax.data._laser_log import LaserOdomLog
from nanoslam_jax.data._loader import LogFormatError

__all__ = ["LASER_SCAN", "ODOMETRY", "TF_MESSAGE", "TF_STATIC", "load_rosbag"]

#: Message type of the scan topic.
LASER_SCAN = "sensor_msgs/msg/LaserScan"
#: Message type of the odometry topic.
ODOMETRY = "nav_msgs/msg/Odometry"
#: Message type of the static transforms.
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
#: The topic of the static transforms (the laser's mounting).
TF_STATIC = "/tf_static"


@dataclass(frozen=True)
class _Scan:
    """One LaserScan message, as read (bag order)."""

    stamp: int  # ns
    frame: str
    ranges: np.ndarray
    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float


def _stamp_ns(stamp: Any) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _seconds(ns: int) -> float:
    """``ns`` in seconds, correctly rounded (the float a decimal ``sec.nanosec`` string parses to)."""
    return float(Fraction(ns, 1_000_000_000))


def _frame(name: str) -> str:
    """A tf frame id without ROS 1's leading slash."""
    return str(name).lstrip("/")


def _yaw(q: Any) -> float:
    """Yaw (rad) of a quaternion ``(x, y, z, w)``, not necessarily of unit norm."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), q.w * q.w + q.x * q.x - q.y * q.y - q.z * q.z)


def _matrix(translation: Any, q: Any) -> np.ndarray:
    """The 4x4 homogeneous transform of a translation and a (normalised) quaternion."""
    x, y, z, w = (float(v) for v in (q.x, q.y, q.z, q.w))
    n = math.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    t = np.eye(4)
    t[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    t[:3, 3] = [float(translation.x), float(translation.y), float(translation.z)]
    return t


class _Bag:
    """An open bag: its topics and the messages of one topic, deserialised, in bag order."""

    def __init__(self, path: Path):
        from rosbags.highlevel import AnyReader, AnyReaderError
        from rosbags.rosbag1 import ReaderError as ReaderError1
        from rosbags.rosbag2 import ReaderError as ReaderError2
        from rosbags.typesys import Stores, get_typestore

        self.path = path
        self._errors = (AnyReaderError, ReaderError1, ReaderError2)
        if path.is_dir() and not (path / "metadata.yaml").is_file():
            raise LogFormatError(
                f"{path}: not a ROS 2 bag directory (no metadata.yaml); expected a ROS 1 .bag file or a ROS 2 bag "
                "directory"
            )
        ros1 = path.is_file() and path.suffix == ".bag"
        store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
        try:
            self._reader = AnyReader([path], default_typestore=store)
            self._reader.open()
        except self._errors as e:
            raise LogFormatError(
                f"{path}: not a readable ROS bag ({e}); expected a ROS 1 .bag file or a ROS 2 bag directory "
                "(sqlite3 or mcap)"
            ) from None
        self.topics: dict[str, Optional[str]] = {name: info.msgtype for name, info in self._reader.topics.items()}

    def close(self) -> None:
        self._reader.close()

    def describe_topics(self) -> str:
        if not self.topics:
            return "the bag has no topics"
        return "the bag has " + ", ".join(f"{name} ({typ})" for name, typ in sorted(self.topics.items()))

    def require(self, topic: str, msgtype: str, key: str) -> None:
        """Raise naming the bag's topics unless it has ``topic`` of type ``msgtype``."""
        if topic not in self.topics:
            raise LogFormatError(f"{self.path}: no topic {topic!r} ({msgtype}; set {key}); {self.describe_topics()}")
        if self.topics[topic] != msgtype:
            raise LogFormatError(
                f"{self.path}: topic {topic!r} holds {self.topics[topic]}, expected {msgtype} (set {key}); "
                f"{self.describe_topics()}"
            )

    def messages(self, topic: str) -> Iterator[tuple[int, Any]]:
        """``(1-based index, message)`` of every message on ``topic``, in bag order."""
        conns = [c for c in self._reader.connections if c.topic == topic]
        index = 0
        try:
            for conn, _, raw in self._reader.messages(connections=conns):
                index += 1
                yield index, self._reader.deserialize(raw, conn.msgtype)
        except self._errors as e:
            raise LogFormatError(f"{self.path} topic {topic} message {index}: cannot be read ({e})") from None


def _read_scans(bag: _Bag, topic: str) -> list[_Scan]:
    scans: list[_Scan] = []
    for i, msg in bag.messages(topic):
        s = _Scan(
            stamp=_stamp_ns(msg.header.stamp),
            frame=_frame(msg.header.frame_id),
            ranges=np.asarray(msg.ranges, dtype=np.float64),
            angle_min=float(msg.angle_min),
            angle_increment=float(msg.angle_increment),
            range_min=float(msg.range_min),
            range_max=float(msg.range_max),
        )
        where = f"{bag.path} topic {topic} message {i} (stamp {_seconds(s.stamp)!r} s)"
        if not (math.isfinite(s.range_max) and s.range_max > 0):
            raise LogFormatError(f"{where}: expected a finite range_max > 0, got {s.range_max!r}")
        if not (math.isfinite(s.range_min) and 0 <= s.range_min < s.range_max):
            raise LogFormatError(f"{where}: expected 0 <= range_min < range_max ({s.range_max!r}), got {s.range_min!r}")
        if not (math.isfinite(s.angle_min) and math.isfinite(s.angle_increment)):
            raise LogFormatError(
                f"{where}: expected finite angle_min and angle_increment, got {s.angle_min!r}, {s.angle_increment!r}"
            )
        if i == 1:
            if s.ranges.size == 0:
                raise LogFormatError(f"{where}: the scan has no beams (empty ranges)")
            if s.ranges.size >= 2 and s.angle_increment == 0:
                raise LogFormatError(
                    f"{where}: angle_increment is 0 with {s.ranges.size} beams; expected the beams' angles to "
                    "increase (or decrease) along the scan"
                )
        else:
            first = scans[0]
            got = (s.ranges.size, s.angle_min, s.angle_increment, s.frame)
            want = (first.ranges.size, first.angle_min, first.angle_increment, first.frame)
            if got != want:
                raise LogFormatError(
                    f"{where}: the scan settings changed; expected the first message's {want[0]} beams, angle_min "
                    f"{want[1]!r}, angle_increment {want[2]!r} in frame {want[3]!r}, got {got[0]} beams, angle_min "
                    f"{got[1]!r}, angle_increment {got[2]!r} in frame {got[3]!r}"
                )
        scans.append(s)
    if not scans:
        raise LogFormatError(f"{bag.path}: topic {topic} has no messages; expected {LASER_SCAN} scans")
    return scans


def _read_odom(bag: _Bag, topic: str) -> tuple[np.ndarray, np.ndarray, str]:
    """Stamps (ns, strictly increasing), poses ``(N, 3)`` and the base frame of the odometry."""
    stamps: list[int] = []
    poses: list[tuple[float, float, float]] = []
    base = ""
    for i, msg in bag.messages(topic):
        t = _stamp_ns(msg.header.stamp)
        where = f"{bag.path} topic {topic} message {i} (stamp {_seconds(t)!r} s)"
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        values = (float(p.x), float(p.y), float(q.x), float(q.y), float(q.z), float(q.w))
        if not all(math.isfinite(v) for v in values):
            raise LogFormatError(f"{where}: expected a finite position and orientation, got {values}")
        if not any(values[2:]):
            raise LogFormatError(f"{where}: the orientation quaternion is zero; expected a rotation")
        if i == 1:
            base = _frame(msg.child_frame_id)
        if stamps and t < stamps[-1]:
            raise LogFormatError(
                f"{where}: the odometry jumps back in time, {_seconds(stamps[-1] - t)!r} s before message "
                f"{i - 1} (stamp {_seconds(stamps[-1])!r} s); expected non-decreasing stamps"
            )
        if stamps and t == stamps[-1]:
            continue  # a repeated stamp: the first message holds the pose
        stamps.append(t)
        poses.append((float(p.x), float(p.y), _yaw(q)))
    if not stamps:
        raise LogFormatError(f"{bag.path}: topic {topic} has no messages; expected {ODOMETRY} poses")
    return np.array(stamps, dtype=np.int64), np.array(poses, dtype=np.float64), base


def _read_tf_static(bag: _Bag) -> dict[str, tuple[str, np.ndarray]]:
    """``child frame -> (parent frame, 4x4 transform parent <- child)`` of the bag's static transforms."""
    if bag.topics.get(TF_STATIC) != TF_MESSAGE:
        return {}
    tree: dict[str, tuple[str, np.ndarray]] = {}
    for _, msg in bag.messages(TF_STATIC):
        for tf in msg.transforms:
            tree[_frame(tf.child_frame_id)] = (
                _frame(tf.header.frame_id),
                _matrix(tf.transform.translation, tf.transform.rotation),
            )
    return tree


def _mounting(tree: dict[str, tuple[str, np.ndarray]], base: str, laser: str) -> Optional[np.ndarray]:
    """``(x, y, theta)`` of frame ``laser`` in frame ``base`` through the chain of ``tree``, or None."""

    def to_root(frame: str) -> tuple[str, np.ndarray]:
        t, seen = np.eye(4), set()
        while frame in tree and frame not in seen:
            seen.add(frame)
            parent, step = tree[frame]
            t, frame = step @ t, parent
        return frame, t

    if not base or not laser:
        return None
    root_b, t_b = to_root(base)
    root_l, t_l = to_root(laser)
    if root_b != root_l:
        return None
    t = np.linalg.solve(t_b, t_l)
    return np.array([t[0, 3], t[1, 3], float(wrap_angle_np(math.atan2(t[1, 0], t[0, 0])))])


def _interpolate(t: np.ndarray, ts: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Poses at times ``t`` (ns, inside ``[ts[0], ts[-1]]``): position linearly, yaw on the circle."""
    if ts.size == 1:
        return np.repeat(poses[:1], t.size, axis=0)
    k = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, ts.size - 2)
    w = ((t - ts[k]) / (ts[k + 1] - ts[k]))[:, None]
    xy = poses[k, :2] + w * (poses[k + 1, :2] - poses[k, :2])
    dyaw = wrap_angle_np(poses[k + 1, 2] - poses[k, 2])
    yaw = wrap_angle_np(poses[k, 2] + w[:, 0] * dyaw)
    return np.column_stack([xy, yaw])


def _laser_pose_arg(laser_pose: Optional[Sequence[float]]) -> Optional[np.ndarray]:
    """The ``laser_pose`` argument as ``(x, y, theta)`` with the angle wrapped, or None; a ValueError unless
    it is three finite numbers."""
    if laser_pose is None:
        return None
    pose_arg = np.asarray(laser_pose, dtype=np.float64)
    if pose_arg.shape != (3,) or not np.all(np.isfinite(pose_arg)):
        raise ValueError(f"laser_pose: expected three finite numbers (x, y, theta), got {laser_pose!r}")
    return np.array([pose_arg[0], pose_arg[1], float(wrap_angle_np(pose_arg[2]))])


def _scans_in_odometry_span(
    path: Path, scan_topic: str, odom_topic: str, stamps: np.ndarray, odom_t: np.ndarray
) -> tuple[np.ndarray, int]:
    """The indices of the scans stamped within the odometry's span, sorted by stamp, and how many scans
    were stamped earlier than the one before them (each with a warning to ``load_rosbag``'s caller)."""
    out_of_order = int(np.count_nonzero(np.diff(stamps) < 0))
    if out_of_order:
        warnings.warn(
            f"{path} topic {scan_topic}: {out_of_order} scans were stamped earlier than the scan before them; "
            "sorted by stamp",
            stacklevel=3,
        )
    order = np.argsort(stamps, kind="stable")
    inside = order[(stamps[order] >= odom_t[0]) & (stamps[order] <= odom_t[-1])]
    before = int(np.count_nonzero(stamps < odom_t[0]))
    after = int(np.count_nonzero(stamps > odom_t[-1]))
    if inside.size == 0:
        raise LogFormatError(
            f"{path}: no scan on {scan_topic} lies within the odometry's time span on {odom_topic} "
            f"({_seconds(int(odom_t[0]))!r} to {_seconds(int(odom_t[-1]))!r} s); scans run from "
            f"{_seconds(int(stamps.min()))!r} to {_seconds(int(stamps.max()))!r} s"
        )
    if before or after:
        warnings.warn(
            f"{path}: dropped {before} scans on {scan_topic} stamped before the first odometry message on "
            f"{odom_topic} and {after} after the last (no odometry to interpolate)",
            stacklevel=3,
        )
    return inside, out_of_order


def _scan_ranges(messages: list[_Scan], inside: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """``(ranges, angles, max_range)`` of the scans ``inside``: no returns set to the largest ``range_max``,
    the beams in increasing angle."""
    first = messages[0]
    max_range = max(m.range_max for m in messages)
    rows = []
    for k in inside:
        m = messages[k]
        r = m.ranges
        ok = np.isfinite(r) & (r >= m.range_min) & (r < m.range_max)
        rows.append(np.where(ok, r, max_range))
    ranges = np.array(rows, dtype=np.float64)
    angles = first.angle_min + np.arange(first.ranges.size) * first.angle_increment
    if first.angle_increment < 0:
        angles, ranges = angles[::-1], ranges[:, ::-1]
    return ranges, angles, max_range


def _laser_mounting(
    path: Path, tree: dict[str, tuple[str, np.ndarray]], base: str, laser: str, pose_arg: Optional[np.ndarray]
) -> np.ndarray:
    """The laser's mounting in the base frame: from ``/tf_static``, else ``pose_arg``, else zero (warnings to
    ``load_rosbag``'s caller where it is zero or ``pose_arg`` is ignored)."""
    mount = _mounting(tree, base, laser)
    if mount is None:
        if tree:
            why = (
                f"{TF_STATIC} has no chain of transforms from the odometry's frame {base!r} to the scans' frame "
                f"{laser!r}"
            )
        else:
            why = f"the bag has no {TF_STATIC}"
        if pose_arg is not None:
            mount = pose_arg
        else:
            mount = np.zeros(3)
            warnings.warn(f"{path}: {why}; the laser's mounting is taken as zero (give laser_pose)", stacklevel=3)
    elif pose_arg is not None and not np.allclose(pose_arg, mount):
        warnings.warn(
            f"{path}: laser_pose {pose_arg.tolist()} ignored; the bag's {TF_STATIC} gives the mounting "
            f"{mount.tolist()} of frame {laser!r} in {base!r}",
            stacklevel=3,
        )
    return mount


def load_rosbag(
    path: str | os.PathLike,
    *,
    scan_topic: str = "/scan",
    odom_topic: str = "/odom",
    laser_pose: Optional[Sequence[float]] = None,
) -> LaserOdomLog:
    """Read a laser log with odometry from a ROS bag.

    Args:
        path: a ROS 1 ``.bag`` file, or a ROS 2 bag directory (the one holding ``metadata.yaml``;
            sqlite3 or mcap storage).
        scan_topic: the topic of the ``sensor_msgs/msg/LaserScan`` messages.
        odom_topic: the topic of the ``nav_msgs/msg/Odometry`` messages.
        laser_pose: the laser's mounting ``(x, y, theta)`` (m, m, rad) in the odometry's base frame,
            used when the bag's ``/tf_static`` does not give it; None: zero (with a warning).

    Returns:
        The scans sorted by ``header.stamp`` (times in s), beam angles ``angle_min + i *
        angle_increment`` in the laser frame (reversed when the increment is negative), no returns
        (not finite, below ``range_min``, at or beyond ``range_max``) set to the largest
        ``range_max``; the odometry pose ``(x, y, yaw)`` of the base frame interpolated to each
        scan's stamp; the laser's mounting in the base frame. Scans stamped before the first or
        after the last odometry message are dropped (with a warning).

    Raises:
        FileNotFoundError: no such file or directory.
        LogFormatError: not a readable bag; a missing topic (the message lists the bag's topics
            and their types); a topic without messages; a scan whose beam count, angles or frame
            differ from the first's; odometry stepping back in time; no scan within the
            odometry's time span. The message names the bag, the topic and the message (1-based
            index in the bag and stamp).
        ValueError: ``laser_pose`` is not three finite numbers.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: ROS bag not found; expected a ROS 1 .bag file or a ROS 2 bag directory")
    pose_arg = _laser_pose_arg(laser_pose)
    bag = _Bag(path)
    try:
        bag.require(scan_topic, LASER_SCAN, "data.scan_topic")
        bag.require(odom_topic, ODOMETRY, "data.odom_topic")
        messages = _read_scans(bag, scan_topic)
        odom_t, odom_pose, base = _read_odom(bag, odom_topic)
        tree = _read_tf_static(bag)
    finally:
        bag.close()

    stamps = np.array([m.stamp for m in messages], dtype=np.int64)
    inside, out_of_order = _scans_in_odometry_span(path, scan_topic, odom_topic, stamps, odom_t)
    ranges, angles, max_range = _scan_ranges(messages, inside)
    mount = _laser_mounting(path, tree, base, messages[0].frame, pose_arg)
    scan_t = stamps[inside]
    scans = LaserScans(
        time=np.array([_seconds(int(t)) for t in scan_t], dtype=np.float64),
        ranges=ranges,
        angles=angles,
        max_range=max_range,
        source=str(path),
    )
    return LaserOdomLog(
        scans=scans,
        odom=_interpolate(scan_t, odom_t, odom_pose),
        laser_pose=mount,
        out_of_order=out_of_order,
        source=str(path),
    )
