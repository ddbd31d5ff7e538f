"""Recordings made from a rendered BOP scene, as a user's camera and robot would give them: a ROS 2 bag
with realsense2_camera's and joint_state_broadcaster's topics (written with rosbags' own writer), or a
recording folder. The robot pauses at each frame's joint positions (joint states 5 ms before and after the
image) and the depth image's stamp wanders a few milliseconds from the colour image's."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from feepe.calibrate.folder import FolderWriter
from feepe.calibrate.recording import RecordedFrame
from kernel.bop import read_frame, read_scene

START_S, PERIOD_S = 1000.0, 0.5


def _stamp(store, t: float):
    Time = store.types["builtin_interfaces/msg/Time"]
    return Time(sec=int(t), nanosec=int(round((t - int(t)) * 1e9)))


def _header(store, t: float, frame_id: str):
    Header = store.types["std_msgs/msg/Header"]
    ros1 = "seq" in Header.__dataclass_fields__
    return Header(**({"seq": 0} if ros1 else {}), stamp=_stamp(store, t), frame_id=frame_id)


def _camera_info(store, t: float, K: np.ndarray, h: int, w: int):
    CameraInfo = store.types["sensor_msgs/msg/CameraInfo"]
    matrices = {"d": np.zeros(5), "k": K.reshape(-1), "r": np.eye(3).reshape(-1),
                "p": np.hstack([K, np.zeros((3, 1))]).reshape(-1)}
    if "K" in CameraInfo.__dataclass_fields__:  # ROS 1 names them in capitals
        matrices = {key.upper(): value for key, value in matrices.items()}
    roi = store.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return CameraInfo(header=_header(store, t, "camera_color_optical_frame"), height=h, width=w,
                      distortion_model="plumb_bob", binning_x=0, binning_y=0, roi=roi, **matrices)


def _image(store, t: float, array: np.ndarray, encoding: str, frame_id: str):
    Image = store.types["sensor_msgs/msg/Image"]
    data = np.ascontiguousarray(array)
    return Image(header=_header(store, t, frame_id), height=data.shape[0], width=data.shape[1], encoding=encoding,
                 is_bigendian=0, step=data.strides[0], data=data.view(np.uint8).reshape(-1))


def write_bag(scene_dir: Path, path: Path, seed: int = 0, storage: str = "mcap", skip_topic: str | None = None,
              depth_offset_s: float = 0.0, exact_depth: bool = False) -> list[int]:
    """The scene as a ROS 2 bag (`storage` mcap or sqlite3) or a ROS 1 bag (ros1, `path` ending in .bag);
    returns the frame ids in bag order. `skip_topic` leaves one topic out;
    `depth_offset_s` shifts every depth stamp (unsynchronised streams); `exact_depth`: a stereo scene's
    exact depth (depth_gt/) instead of its sensor's."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if storage == "ros1" else Stores.ROS2_HUMBLE)
    meta, ids = read_scene(scene_dir)
    rng = np.random.default_rng(seed)
    ns = "/camera/camera"
    topics = {"color": (f"{ns}/color/image_raw", "sensor_msgs/msg/Image"),
              "depth": (f"{ns}/aligned_depth_to_color/image_raw", "sensor_msgs/msg/Image"),
              "info": (f"{ns}/color/camera_info", "sensor_msgs/msg/CameraInfo"),
              "joints": ("/joint_states", "sensor_msgs/msg/JointState")}
    messages = []
    for k, i in enumerate(ids):
        f = read_frame(scene_dir, i)
        t = START_S + PERIOD_S * k
        if k == 0:
            messages.append((t, "info", _camera_info(store, t, f.K, *f.rgb.shape[:2])))
        messages.append((t, "color", _image(store, t, f.rgb, "rgb8", "camera_color_optical_frame")))
        t_depth = t + depth_offset_s + rng.uniform(-0.008, 0.008)
        depth = f.depth_gt if exact_depth else f.depth
        messages.append((t_depth, "depth", _image(store, t_depth, depth.astype(np.float32), "32FC1",
                                                  "camera_color_optical_frame")))
        for dt in (-0.005 + rng.uniform(-0.002, 0.002), 0.005 + rng.uniform(-0.002, 0.002)):
            js = store.types["sensor_msgs/msg/JointState"](header=_header(store, t + dt, ""), name=list(meta.joint_names),
                                                           position=np.asarray(f.joint_positions, float),
                                                           velocity=np.zeros(0), effort=np.zeros(0))
            messages.append((t + dt, "joints", js))
    with _writer(path, storage) as writer:
        connections = {key: writer.add_connection(topic, msgtype, typestore=store)
                       for key, (topic, msgtype) in topics.items() if key != skip_topic}
        serialize = store.serialize_ros1 if storage == "ros1" else store.serialize_cdr
        for t, key, msg in sorted(messages, key=lambda m: m[0]):
            if key in connections:
                writer.write(connections[key], int(t * 1e9), serialize(msg, topics[key][1]))
    return ids


def _writer(path: Path, storage: str):
    if storage == "ros1":
        from rosbags.rosbag1 import Writer
        return Writer(path)
    from rosbags.rosbag2 import StoragePlugin, Writer
    return Writer(path, version=9, storage_plugin=StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3)


def write_folder(scene_dir: Path, folder: Path, masks: bool = False, flange: bool = False) -> list[int]:
    """The scene as a recording folder (feepe/calibrate/folder.py); depth in 0.1 mm units as BOP stores it.
    `masks`: the end-effector's visible masks too; `flange`: the end-effector's poses instead of joints."""
    meta, ids = read_scene(scene_dir)
    writer = FolderWriter(folder, depth_scale=1e-4)
    for i in ids:
        f = read_frame(scene_dir, i)
        joints = None if flange else dict(zip(meta.joint_names, map(float, f.joint_positions)))
        writer.add(RecordedFrame(f"{i:06d}", float(i), f.rgb, f.depth, f.K, joints, f.T_base_ee,
                                 f.mask_visib if masks else None))
    writer.close()
    return ids
