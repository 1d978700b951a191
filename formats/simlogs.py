"""Writing a simulated run in every format dynslam reads, so every reader is tested against
the same world: Carmen (FLASER or ROBOTLASER1 with ODOM), Player 0.3.0 text, ROS1 bag, ROS2 bag
(sqlite3 or mcap storage) and a plain MCAP file of ROS1 messages.

ROS outputs carry ``/scan`` (sensor_msgs/LaserScan, frame ``laser``, no return = +inf per
REP 117) and ``/odom`` (nav_msgs/Odometry, ``odom → base_link``), stamped with the scan time.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from dynslam_cli.simulate import LaserModel, SimStep
from dynslam_formats.carmen import format_flaser, format_odom, format_param, format_robotlaser1

EPOCH_S = 1_700_000_000  # simulated time 0 as a plausible ROS time
TEXT_FORMATS = ("carmen", "player")  # stamped from 0, like the truth


def stamp_offset(fmt: str) -> float:
    """Seconds the log's stamps in format ``fmt`` are ahead of the truth's times."""
    return 0.0 if fmt in TEXT_FORMATS else float(EPOCH_S)


def write_carmen(out: TextIO, steps: Iterable[SimStep], laser: LaserModel, record: str,
                 world: str) -> int:
    """Write the simulated steps as a Carmen log; returns the number of scans."""
    fov = math.radians(laser.fov_deg)
    step = fov / max(laser.beams - 1, 1)
    out.write("# CARMEN Logfile\n# written by dynslam simulate, world " + world + "\n")
    out.write(format_param("laser_front_laser_fov", f"{laser.fov_deg:g}"))
    out.write(format_param("laser_front_laser_resolution", f"{math.degrees(step):.9g}"))
    out.write(format_param("laser_front_laser_max_range", f"{laser.max_range_m:g}"))
    n = 0
    for s in steps:
        out.write(format_odom(s.stamp, s.odom))
        if record == "flaser":
            out.write(format_flaser(s.stamp, s.ranges, s.odom))
        else:
            out.write(format_robotlaser1(s.stamp, s.ranges, -fov / 2, step, laser.max_range_m,
                                         s.odom))
        n += 1
    return n


def write_player(path: Path, steps: Iterable[SimStep], laser: LaserModel) -> int:
    fov = math.radians(laser.fov_deg)
    res = fov / max(laser.beams - 1, 1)
    n = 0
    with open(path, "w", encoding="utf-8", newline="\n") as f:
        f.write("## Player version 3.0.2\n## File version 0.3.0\n# written by dynslam simulate\n")
        for s in steps:
            t = f"{s.stamp:014.3f} 16777343 6665"
            o = s.odom
            f.write(f"{t} position2d 00 001 001 {o.x:+.6f} {o.y:+.6f} {o.theta:+.6f} "
                    "+0.000 +0.000 +0.000 0\n")
            pairs = " ".join(f"{r:.3f} 0" for r in s.ranges)
            f.write(f"{t} laser 00 001 001 {n:04d} {-fov / 2:+.6f} {fov / 2:+.6f} {res:+.8f} "
                    f"{laser.max_range_m:+.4f} {len(s.ranges):04d} {pairs}\n")
            n += 1
    return n


def _messages(ts: Any, s: SimStep, laser: LaserModel, n: int) -> tuple[Any, Any, int]:
    """(LaserScan, Odometry, stamp ns) for step ``n``, built from typestore ``ts`` (ROS 1:
    ``header.seq`` counts the steps, as a publisher numbers its messages)."""
    t = ts.types
    ns = round((EPOCH_S + s.stamp) * 1e9)
    time = t["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
    fov = math.radians(laser.fov_deg)
    ranges = np.where(s.ranges >= laser.max_range_m, np.inf, s.ranges).astype(np.float32)
    header = t["std_msgs/msg/Header"]
    hdr = {"stamp": time}
    if "seq" in header.__dataclass_fields__:
        hdr["seq"] = n
    scan = t["sensor_msgs/msg/LaserScan"](
        header=header(**hdr, frame_id="laser"), angle_min=-fov / 2, angle_max=fov / 2,
        angle_increment=fov / max(laser.beams - 1, 1), time_increment=0.0, scan_time=0.1,
        range_min=0.02, range_max=laser.max_range_m, ranges=ranges,
        intensities=np.zeros(0, np.float32))
    q = t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(s.odom.theta / 2),
                                          w=math.cos(s.odom.theta / 2))
    pose = t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=s.odom.x, y=s.odom.y, z=0.0), orientation=q)
    zero3 = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    odom = t["nav_msgs/msg/Odometry"](
        header=header(**hdr, frame_id="odom"), child_frame_id="base_link",
        pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](linear=zero3, angular=zero3),
            covariance=np.zeros(36)))
    return scan, odom, ns


def write_rosbag1(path: Path, steps: Iterable[SimStep], laser: LaserModel) -> int:
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    with Writer(path) as w:
        return _write_bag(w, ts, ts.serialize_ros1, steps, laser)


def write_rosbag2(path: Path, steps: Iterable[SimStep], laser: LaserModel,
                  storage: str = "sqlite3") -> int:
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as w:
        return _write_bag(w, ts, ts.serialize_cdr, steps, laser)


def _write_bag(w: Any, ts: Any, serialize: Any, steps: Iterable[SimStep],
               laser: LaserModel) -> int:
    """/odom then /scan for every step, through an open rosbags writer."""
    cs = w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=ts)
    co = w.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=ts)
    n = 0
    for s in steps:
        scan, odom, ns = _messages(ts, s, laser, n)
        w.write(co, ns, serialize(odom, "nav_msgs/msg/Odometry"))
        w.write(cs, ns, serialize(scan, "sensor_msgs/msg/LaserScan"))
        n += 1
    return n


def write_mcap_ros1(path: Path, steps: Iterable[SimStep], laser: LaserModel) -> int:
    """A plain MCAP file (profile ``ros1``) of ROS1 messages, as rosbag1-to-MCAP tools write."""
    from mcap.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    n = 0
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="ros1", library="dynslam")
        ids = {}
        for topic, name in (("/scan", "sensor_msgs/msg/LaserScan"),
                            ("/odom", "nav_msgs/msg/Odometry")):
            ros1_name = name.replace("/msg/", "/")
            schema = w.register_schema(ros1_name, "ros1msg",
                                       ts.generate_msgdef(name)[0].encode())
            ids[topic] = w.register_channel(topic, "ros1", schema)
        for s in steps:
            scan, odom, ns = _messages(ts, s, laser, n)
            w.add_message(ids["/odom"], log_time=ns, publish_time=ns, sequence=n,
                          data=ts.serialize_ros1(odom, "nav_msgs/msg/Odometry"))
            w.add_message(ids["/scan"], log_time=ns, publish_time=ns, sequence=n,
                          data=ts.serialize_ros1(scan, "sensor_msgs/msg/LaserScan"))
            n += 1
        w.finish()
    return n


def write_simulated(fmt: str, path: Path, steps: Iterable[SimStep], laser: LaserModel,
                    record: str = "flaser", world: str = "") -> int:
    """Write ``steps`` in format ``fmt`` (carmen with ``record`` flaser|robotlaser1, player,
    rosbag1, rosbag2, rosbag2-mcap, mcap); returns the number of scans."""
    if fmt == "carmen":
        with open(path, "w", encoding="utf-8", newline="\n") as f:
            return write_carmen(f, steps, laser, record, world)
    if fmt == "player":
        return write_player(path, steps, laser)
    if fmt == "rosbag1":
        return write_rosbag1(path, steps, laser)
    if fmt in ("rosbag2", "rosbag2-mcap"):
        return write_rosbag2(path, steps, laser, "mcap" if fmt.endswith("mcap") else "sqlite3")
    if fmt == "mcap":
        return write_mcap_ros1(path, steps, laser)
    raise ValueError(f"unknown simulated log format {fmt!r}")
