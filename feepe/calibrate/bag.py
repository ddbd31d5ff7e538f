"""A recording as a ROS 1 bag, a ROS 2 bag (sqlite3 or MCAP) or an MCAP file, read with `rosbags` (no ROS
installed). Colour frames are paired with the depth image nearest their header stamp (within
`--sync-tolerance`) and with the joint positions interpolated at that stamp between the two joint-state
messages around it (at most `--joint-gap` apart). Topic defaults match realsense2_camera (ROS 2, namespace
/camera/camera, aligned depth on) and ros2_control's joint_state_broadcaster."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from feepe.calibrate.recording import RecordedFrame, Recording, interpolate_joints, intrinsics, nearest
from kernel.errors import UserError


@dataclass(frozen=True)
class Topics:
    color: str = "/camera/camera/color/image_raw"
    depth: str = "/camera/camera/aligned_depth_to_color/image_raw"
    camera_info: str = "/camera/camera/color/camera_info"
    joint_states: str = "/joint_states"

    @classmethod
    def parse(cls, text: str | None) -> "Topics":
        """`color=/cam/image,depth=none,...`; depth=none reads an RGB camera."""
        if not text:
            return cls()
        given = {}
        for item in text.split(","):
            key, _, value = item.partition("=")
            if key.strip() not in cls.__dataclass_fields__ or not value.strip():
                raise UserError(f"--topics {text!r}: give key=topic pairs for {', '.join(cls.__dataclass_fields__)}")
            given[key.strip()] = value.strip()
        return cls(**given)


def is_bag(path: Path) -> bool:
    path = Path(path)
    return path.suffix in (".bag", ".mcap", ".db3") or (path.is_dir() and (path / "metadata.yaml").is_file())


def read_bag(path: Path, topics: Topics, sync_tolerance: float, joint_gap: float) -> Recording:
    path = Path(path)
    bag = path.parent if path.suffix == ".db3" else path
    store = get_typestore(Stores.ROS2_HUMBLE)
    try:
        with AnyReader([bag], default_typestore=store) as reader:
            by_topic = {c.topic: c for c in reader.connections}
            wanted = [topics.color, topics.camera_info, topics.joint_states]
            wanted += [] if topics.depth == "none" else [topics.depth]
            missing = [t for t in wanted if t not in by_topic]
            if missing:
                raise UserError(f"{path}: no topic {', '.join(missing)} (it has {', '.join(sorted(by_topic))}); "
                                "name yours with --topics color=...,depth=...,camera_info=...,joint_states=...")
            info = _first(reader, by_topic[topics.camera_info])
            K, _, _ = intrinsics({"k": list(info.k if hasattr(info, "k") else info.K)},  # ROS 2 k, ROS 1 K
                                 f"{path} {topics.camera_info}")
            names, js_stamps, positions = _joint_states(reader, by_topic[topics.joint_states])
            color = _stamps(reader, by_topic[topics.color])
            depth = None if topics.depth == "none" else _stamps(reader, by_topic[topics.depth])
    except UserError:
        raise
    except Exception as exc:  # rosbags' own errors for a file it cannot read
        raise UserError(f"{path}: not a bag rosbags reads ({type(exc).__name__}: {exc})") from None
    pairs, dropped = [], {"depth": 0, "joints": 0}
    for i, t in enumerate(color):
        j = None if depth is None else nearest(depth, t, sync_tolerance)
        q = interpolate_joints(js_stamps, positions, t, joint_gap)
        if depth is not None and j is None:
            dropped["depth"] += 1
        elif q is None:
            dropped["joints"] += 1
        else:
            pairs.append((i, j, dict(zip(names, map(float, q)))))
    if not pairs:
        raise UserError(_unsynchronised(path, color, depth, js_stamps, dropped, sync_tolerance, joint_gap))
    sync = {"sync_tolerance_s": sync_tolerance, "joint_gap_s": joint_gap, "color_frames": len(color),
            "dropped_no_depth": dropped["depth"], "dropped_no_joints": dropped["joints"],
            "worst_depth_offset_s": 0.0 if depth is None else float(max(abs(depth[j] - color[i]) for i, j, _ in pairs))}

    def read():
        wanted_depth: dict[int, list[int]] = {}  # a depth image may be the nearest to two colour frames
        for i, j, _ in pairs:
            if j is not None:
                wanted_depth.setdefault(j, []).append(i)
        frames = {i: q for i, _, q in pairs}
        images, depths = {}, {}
        with AnyReader([bag], default_typestore=store) as reader:
            by_topic = {c.topic: c for c in reader.connections}
            connections = [by_topic[topics.color]] + ([] if depth is None else [by_topic[topics.depth]])
            counters = {topics.color: -1, topics.depth: -1}
            for connection, _, raw in reader.messages(connections=connections):
                counters[connection.topic] += 1
                k = counters[connection.topic]
                if connection.topic == topics.color and k in frames:
                    images[k] = reader.deserialize(raw, connection.msgtype)
                elif connection.topic == topics.depth and k in wanted_depth:
                    d = reader.deserialize(raw, connection.msgtype)
                    depths.update({i: d for i in wanted_depth[k]})
                for i in sorted(set(images) & (set(depths) if depth is not None else set(images))):
                    msg = images.pop(i)
                    d = depths.pop(i) if depth is not None else None
                    yield RecordedFrame(str(_ns(msg.header.stamp)), color[i], colour_image(msg), None if d is None
                                        else depth_image(d), K, frames[i])

    return Recording(str(path), len(pairs), read, sync)


def colour_image(msg) -> np.ndarray:
    """sensor_msgs/Image in rgb8, bgr8, rgba8, bgra8 or mono8 as (H, W, 3) uint8 RGB."""
    channels = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1}
    if msg.encoding not in channels:
        raise UserError(f"colour image encoding {msg.encoding!r} is not read; publish rgb8, bgr8, rgba8, bgra8 or mono8")
    n = channels[msg.encoding]
    rows = np.frombuffer(bytes(msg.data), np.uint8).reshape(msg.height, msg.step)
    image = rows[:, :msg.width * n].reshape(msg.height, msg.width, n)
    if n == 1:
        return np.repeat(image, 3, axis=2)
    image = image[..., :3]
    return np.ascontiguousarray(image[..., ::-1] if msg.encoding.startswith("bgr") else image)


def depth_image(msg) -> np.ndarray:
    """sensor_msgs/Image depth in metres: 16UC1 (mm, as realsense2_camera publishes) or 32FC1 (m), REP 118;
    NaN and inf as no depth."""
    types = {"16UC1": ("<u2", 1e-3), "mono16": ("<u2", 1e-3), "32FC1": ("<f4", 1.0)}
    if msg.encoding not in types:
        raise UserError(f"depth image encoding {msg.encoding!r} is not read; publish 16UC1 (mm) or 32FC1 (m)")
    dtype, scale = types[msg.encoding]
    dtype = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    rows = np.frombuffer(bytes(msg.data), np.uint8).reshape(msg.height, msg.step)
    depth = rows[:, :msg.width * dtype.itemsize].copy().view(dtype).reshape(msg.height, msg.width).astype(float)
    depth *= scale
    depth[~np.isfinite(depth)] = 0.0
    return depth


def _ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _first(reader, connection):
    for _, _, raw in reader.messages(connections=[connection]):
        return reader.deserialize(raw, connection.msgtype)
    raise UserError(f"topic {connection.topic} holds no message")


def _stamps(reader, connection) -> np.ndarray:
    """Header stamps (s) of a topic's messages, in the bag's order."""
    return np.array([_ns(reader.deserialize(raw, connection.msgtype).header.stamp) * 1e-9
                     for _, _, raw in reader.messages(connections=[connection])])


def _joint_states(reader, connection) -> tuple[list[str], np.ndarray, np.ndarray]:
    """The joint names and, per message, stamp and positions in that order (messages naming the joints in
    another order are reordered; ones lacking a joint are skipped)."""
    names, stamps, rows = None, [], []
    for _, _, raw in reader.messages(connections=[connection]):
        msg = reader.deserialize(raw, connection.msgtype)
        if names is None:
            names = list(msg.name)
        position = dict(zip(msg.name, msg.position))
        if all(n in position for n in names):
            stamps.append(_ns(msg.header.stamp) * 1e-9)
            rows.append([position[n] for n in names])
    if names is None:
        raise UserError(f"topic {connection.topic} holds no joint state")
    order = np.argsort(stamps, kind="stable")
    return names, np.asarray(stamps)[order], np.asarray(rows, float)[order]


def _unsynchronised(path, color, depth, js, dropped, tolerance, gap) -> str:
    span = lambda s: f"{s.min():.3f}-{s.max():.3f} s" if len(s) else "empty"
    if dropped["depth"]:
        return (f"{path}: no colour frame has a depth image within {tolerance} s (colour {span(color)}, depth "
                f"{span(depth)}); are the streams from one clock? widen --sync-tolerance if they are")
    return (f"{path}: no colour frame falls between two joint states at most {gap} s apart (colour {span(color)}, "
            f"joint_states {span(js)}); are the streams from one clock? widen --joint-gap if they are")
