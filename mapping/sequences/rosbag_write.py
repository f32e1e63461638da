"""A ScanNet-layout recording (``calnav export-sequence``) written as a ROS bag, with the
``rosbags`` writers and type stores: ROS 1 ``.bag``, ROS 2 sqlite3 or mcap. Data with known
answers for the ``rosbag`` reader's tests and the bench: mapping the bag gives the folder's map.

The bag holds what an RGB-D robot records (topics of ``BagOptions.topics``, default the
RealSense preset): colour (raw ``rgb8`` = the folder's decoded JPEG, or ``CompressedImage``
holding the folder's JPEG bytes), depth (raw ``16UC1`` millimetres, raw ``32FC1`` metres, or
``compressedDepth`` = 12-byte header + the folder's PNG), CameraInfo of both, optional labels
(``16UC1`` class id + 1), and TF: ``map -> base_link`` on ``/tf`` at the frame stamps (the
camera pose times the inverse of the mounting), ``base_link -> camera_link -> <optical frame>``
on ``/tf_static``; or a ``nav_msgs/Odometry`` / ``geometry_msgs/PoseStamped`` pose topic of the camera itself.
Faults a real recording has, on request (``BagOptions``): dropped or NaN pose samples, two frames at
one stamp, a frame's messages written twice.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
from scipy.spatial.transform import Rotation

from calnav.mapping.sequences.readers import Sequence, SequenceConfig, depth_from_raw
from calnav.mapping.sequences.rosbag_config import ROSBAG_PRESETS, RosbagPreset
from calnav.mapping.sequences.rosbag_tf import NS

START_NS = 1_700_000_000 * NS          # first frame stamp (a plausible wall-clock time)
LATENCY_NS = 3_000_000                 # images are logged 3 ms after their stamp, as a recorder would
OPTICAL_FRAME = "camera_color_optical_frame"
# camera_link (x forward, z up) -> optical frame (z forward, x right, y down): REP 103's rotation
OPTICAL_QUAT = (-0.5, 0.5, -0.5, 0.5)
# where the camera sits on the robot: base_link -> camera_link, x y z metres, quaternion xyzw
MOUNT = ((0.12, -0.03, 1.1), tuple(Rotation.from_euler("z", 7.0, degrees=True).as_quat()))


@dataclass
class BagOptions:
    """How ``scannet_to_bag`` writes the bag."""

    storage: Literal["ros1", "sqlite3", "mcap"] = "ros1"
    color: Literal["raw", "jpeg"] = "raw"
    depth: Literal["16UC1", "32FC1", "compressedDepth"] = "16UC1"
    topics: RosbagPreset = field(default_factory=lambda: ROSBAG_PRESETS.get("realsense"))
    semantic_topic: str = ""          # "" = no labels
    period_s: float = 0.15            # time between frames, seconds (a dropped pose leaves a 0.3 s gap: over pose_max_gap_s)
    extra_color: bool = False         # colour at twice the frame rate: an image between frames, with no depth near it
    extra_depth: bool = False         # depth at twice the frame rate: an image between frames
    drop_poses: tuple[int, ...] = ()  # frames whose TF sample (or odometry) is not written
    bad_pose: Literal["drop", "nan"] = "drop"   # a frame whose folder pose is not finite: no sample, or a NaN one
    shared_stamp: tuple[int, ...] = ()   # frames stamped as the frame before them: two frames, two TF poses, one stamp
    repeat: tuple[int, ...] = ()      # frames whose messages (images, TF / odometry) are written twice, identical
    second_depth: tuple[int, ...] = ()   # frames with a second, different raw depth image at their stamp (1 cm farther)
    pose: Literal["tf", "odometry", "pose_stamped"] = "tf"   # TF, or the camera's pose on pose_topic
    pose_topic: str = "/odom"
    distortion: tuple[float, ...] = ()   # CameraInfo D written (plumb_bob); the images are written as they are
    tf_child: str = "base_link"       # the moving TF frame (map -> tf_child); the mounting hangs from base_link
    depth_encoding: str = ""          # the raw depth images' stated encoding; "" = the depth option's
    depth_frame: str = OPTICAL_FRAME  # the depth images' header.frame_id
    tf_type: Literal["tf2_msgs/msg/TFMessage", "tf/msg/tfMessage"] = "tf2_msgs/msg/TFMessage"   # ROS 1 bags of
                                      # the tf era (e.g. TUM RGB-D) record tf/tfMessage, the same fields


def open_writer(path: Path, storage: str):
    """A rosbags writer of ``path`` for ``storage`` ("ros1", "sqlite3", "mcap"; not yet opened), its
    typestore and whether it is ROS 1: what ``BagWriter`` takes."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    if storage == "ros1":
        from rosbags.rosbag1 import Writer

        ts = get_typestore(Stores.ROS1_NOETIC)
        # rosbags' ROS 1 store has no tf2_msgs (nor the older tf): their one-field definition, as ROS 1 ships it
        for name in ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage"):
            ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", name))
        return Writer(path), ts, True
    from rosbags.rosbag2 import StoragePlugin, Writer

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    return Writer(path, version=9, storage_plugin=plugin), get_typestore(Stores.ROS2_HUMBLE), False


class BagWriter:
    """Message construction and writing for one bag (ROS 1 or ROS 2 types): ``BagWriter(*open_writer(path,
    storage))`` once the writer is opened; ``write(topic, msgtype, log_ns, msg)``."""

    def __init__(self, writer, ts, ros1: bool):
        self.writer, self.ts, self.ros1, self.conns = writer, ts, ros1, {}
        self.t = ts.types

    def header(self, stamp_ns: int, frame: str):
        stamp = self.t["builtin_interfaces/msg/Time"](sec=stamp_ns // NS, nanosec=stamp_ns % NS)
        kw = {"seq": 0} if self.ros1 else {}
        return self.t["std_msgs/msg/Header"](**kw, stamp=stamp, frame_id=frame)

    def write(self, topic: str, msgtype: str, log_ns: int, msg) -> None:
        if topic not in self.conns:
            self.conns[topic] = self.writer.add_connection(topic, msgtype, typestore=self.ts)
        data = self.ts.serialize_ros1(msg, msgtype) if self.ros1 else self.ts.serialize_cdr(msg, msgtype)
        self.writer.write(self.conns[topic], log_ns, data)

    def image(self, stamp: int, frame: str, encoding: str, px: np.ndarray):
        h, w = px.shape[:2]
        data = np.ascontiguousarray(px).view(np.uint8).reshape(-1)
        return self.t["sensor_msgs/msg/Image"](header=self.header(stamp, frame), height=h, width=w, encoding=encoding,
                                               is_bigendian=0, step=data.size // h, data=data)

    def compressed(self, stamp: int, frame: str, fmt: str, data: bytes):
        return self.t["sensor_msgs/msg/CompressedImage"](header=self.header(stamp, frame), format=fmt,
                                                         data=np.frombuffer(data, np.uint8).copy())

    def camera_info(self, stamp: int, frame: str, k: np.ndarray, size: tuple[int, int], d: tuple[float, ...]):
        p = np.zeros((3, 4))
        p[:, :3] = k
        arrays = {"k": k.reshape(-1).astype(np.float64), "d": np.array(d, np.float64), "r": np.eye(3).reshape(-1),
                  "p": p.reshape(-1)}
        if self.ros1:
            arrays = {name.upper(): a for name, a in arrays.items()}
        roi = self.t["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        return self.t["sensor_msgs/msg/CameraInfo"](header=self.header(stamp, frame), height=size[1], width=size[0],
                                                    distortion_model="plumb_bob", **arrays, binning_x=0, binning_y=0,
                                                    roi=roi)

    def transform(self, stamp: int, parent: str, child: str, t, q):
        g = self.t
        tr = g["geometry_msgs/msg/Transform"](translation=g["geometry_msgs/msg/Vector3"](x=t[0], y=t[1], z=t[2]),
                                              rotation=g["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]))
        return g["geometry_msgs/msg/TransformStamped"](header=self.header(stamp, parent), child_frame_id=child,
                                                       transform=tr)

    def tf(self, topic: str, log_ns: int, transforms: list, msgtype: str = "tf2_msgs/msg/TFMessage") -> None:
        self.write(topic, msgtype, log_ns, self.t[msgtype](transforms=transforms))

    def pose(self, t, q):
        g = self.t
        return g["geometry_msgs/msg/Pose"](position=g["geometry_msgs/msg/Point"](x=t[0], y=t[1], z=t[2]),
                                           orientation=g["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]))

    def pose_stamped(self, stamp: int, t, q):
        return self.t["geometry_msgs/msg/PoseStamped"](header=self.header(stamp, "map"), pose=self.pose(t, q))

    def odometry(self, stamp: int, t, q):
        g = self.t
        pose = self.pose(t, q)
        zero = g["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
        return g["nav_msgs/msg/Odometry"](
            header=self.header(stamp, "map"), child_frame_id=OPTICAL_FRAME,
            pose=g["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=g["geometry_msgs/msg/TwistWithCovariance"](twist=g["geometry_msgs/msg/Twist"](linear=zero, angular=zero),
                                                            covariance=np.zeros(36)))


def mount_matrix() -> np.ndarray:
    """base_link -> optical frame (4, 4): the mounting times the optical rotation."""
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(MOUNT[1]).as_matrix()
    m[:3, 3] = MOUNT[0]
    o = np.eye(4)
    o[:3, :3] = Rotation.from_quat(OPTICAL_QUAT).as_matrix()
    return m @ o


def scannet_to_bag(folder, bag, options: BagOptions | None = None) -> Path:
    """Write the ScanNet-layout recording ``folder`` as the bag ``bag`` (see the module docstring);
    frame i is stamped ``START_NS + i * period_s``. Returns ``bag``."""
    opt = options or BagOptions()
    folder, bag = Path(folder), Path(bag)
    seq = Sequence(folder, "scannet")
    all_ids = sorted(int(p.stem) for p in (folder / "depth").glob("*.png"))
    writer, ts, ros1 = open_writer(bag, opt.storage)
    writer.open()
    b = BagWriter(writer, ts, ros1)
    period = int(round(opt.period_s * NS))
    unmount = np.linalg.inv(mount_matrix())   # optical frame -> base_link
    top = opt.topics
    try:
        b.tf("/tf_static", START_NS, [b.transform(START_NS, "base_link", "camera_link", *MOUNT),
                                      b.transform(START_NS, "camera_link", OPTICAL_FRAME, (0.0, 0.0, 0.0), OPTICAL_QUAT)],
             opt.tf_type)
        for info_topic, k, size in ((top.color_info, seq.k_color, seq.color_size), (top.depth_info, seq.k_depth, seq.depth_size)):
            b.write(info_topic, "sensor_msgs/msg/CameraInfo", START_NS,
                    b.camera_info(START_NS, OPTICAL_FRAME, k, size, opt.distortion))
        stamp = START_NS
        for n, i in enumerate(all_ids):
            stamp = stamp if i in opt.shared_stamp else START_NS + n * period
            for _ in range(2 if i in opt.repeat else 1):
                _write_frame(b, opt, folder, i, stamp, unmount)
    finally:
        writer.close()
    return bag


def _write_frame(b: BagWriter, opt: BagOptions, folder: Path, i: int, stamp: int, unmount: np.ndarray) -> None:
    """Frame ``i``'s messages at ``stamp``: its pose (TF or the pose topic), colour, depth, labels."""
    import cv2

    top = opt.topics
    pose = np.loadtxt(folder / "pose" / f"{i}.txt")
    finite = bool(np.isfinite(pose).all())
    if i not in opt.drop_poses and (finite or opt.bad_pose == "nan"):
        m = pose @ unmount if opt.pose == "tf" and finite else pose
        # a non-finite pose (ScanNet's -inf) is written as a NaN sample: what a tracker that lost itself sends
        t, quat = (m[:3, 3], Rotation.from_matrix(m[:3, :3]).as_quat()) if finite else \
            (np.full(3, np.nan), np.full(4, np.nan))
        if opt.pose == "tf":
            b.tf("/tf", stamp, [b.transform(stamp, "map", opt.tf_child, t, quat)], opt.tf_type)
        elif opt.pose == "odometry":
            b.write(opt.pose_topic, "nav_msgs/msg/Odometry", stamp, b.odometry(stamp, t, quat))
        else:
            b.write(opt.pose_topic, "geometry_msgs/msg/PoseStamped", stamp, b.pose_stamped(stamp, t, quat))
    log = stamp + LATENCY_NS
    _write_color(b, opt, top.color, stamp, log, folder / "color" / f"{i}.jpg")
    _write_depth(b, opt, top.depth, stamp, log, folder / "depth" / f"{i}.png")
    if i in opt.second_depth:
        mm = cv2.imread(str(folder / "depth" / f"{i}.png"), cv2.IMREAD_UNCHANGED)
        b.write(top.depth, "sensor_msgs/msg/Image", log, b.image(stamp, opt.depth_frame, "16UC1", mm + np.uint16(10)))
    sem = folder / "semantic" / f"{i}.png"
    if opt.semantic_topic and sem.exists():
        b.write(opt.semantic_topic, "sensor_msgs/msg/Image", log,
                b.image(stamp, OPTICAL_FRAME, "16UC1", cv2.imread(str(sem), cv2.IMREAD_UNCHANGED)))
    half = stamp + int(round(opt.period_s * NS)) // 2   # the extra images between frames: the frame's own pixels, restamped
    if opt.extra_color:
        _write_color(b, opt, top.color, half, half + LATENCY_NS, folder / "color" / f"{i}.jpg")
    if opt.extra_depth:
        _write_depth(b, opt, top.depth, half, half + LATENCY_NS, folder / "depth" / f"{i}.png")


def _write_color(b: BagWriter, opt: BagOptions, topic: str, stamp: int, log: int, path: Path) -> None:
    import cv2

    if opt.color == "jpeg":
        b.write(topic + "/compressed", "sensor_msgs/msg/CompressedImage", log,
                b.compressed(stamp, OPTICAL_FRAME, "rgb8; jpeg compressed bgr8", path.read_bytes()))
    else:
        rgb = cv2.cvtColor(cv2.imread(str(path), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
        b.write(topic, "sensor_msgs/msg/Image", log, b.image(stamp, OPTICAL_FRAME, "rgb8", rgb))


def _write_depth(b: BagWriter, opt: BagOptions, topic: str, stamp: int, log: int, path: Path) -> None:
    import cv2

    if opt.depth == "compressedDepth":   # ConfigHeader {int32 format = 0 (INV_DEPTH); float32 depthParam[2] = 0}
        header = np.array([0], "<i4").tobytes() + np.zeros(2, "<f4").tobytes()
        b.write(topic + "/compressedDepth", "sensor_msgs/msg/CompressedImage", log,
                b.compressed(stamp, opt.depth_frame, "16UC1; compressedDepth png", header + path.read_bytes()))
        return
    mm = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    px = depth_from_raw(mm, SequenceConfig()) if opt.depth == "32FC1" else mm
    b.write(topic, "sensor_msgs/msg/Image", log, b.image(stamp, opt.depth_frame, opt.depth_encoding or opt.depth, px))
