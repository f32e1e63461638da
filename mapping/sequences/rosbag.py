"""The ``rosbag`` sequence layout: a ROS 1 ``.bag`` or a ROS 2 bag (its directory with
``metadata.yaml``, sqlite3 ``.db3`` or ``.mcap`` storage) read with ``rosbags`` (pure Python, no
ROS install; the ``[ros]`` extra) as a stream of posed RGB-D frames.

A frame is a colour image (``sequence.rosbag.color_topic``; its index is the image's number on
that topic, from 0) with the depth image nearest in stamp within ``sync_tolerance_s``, at the
camera pose of the depth image's stamp: from TF (the chain from ``fixed_frame`` to the colour
camera's optical frame; ``/tf_static`` edges constant, ``/tf`` edges interpolated) or from a
pose topic and ``camera_extrinsic``. Colour frames without a depth image in tolerance or
without a pose (the pose track has no samples around the stamp at most ``pose_max_gap_s``
apart), with a NaN pose sample at or across its stamp, sharing its stamp with another colour
image, repeating an earlier message, or read at a stamp holding two different depth images or
pose samples are skipped and counted (``skips``: ``mapping.sequences.skips``, the folders'
rule). Depth must be registered to the colour camera (same optical frame; another resolution / K is resampled by ``Registration``);
depth in another optical frame is refused. Images with distortion (CameraInfo ``D`` not zero)
are undistorted onto K (``rosbag_camera``). See ``docs/sequences.md``.

Opening reads the bag once (headers, CameraInfo, TF, poses; every problem is one ValueError
line before any frame is decoded); ``frames()`` reads it again, decoding one frame at a time.
"""
from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np

from calnav.mapping.sequences import rosbag_images as img
from calnav.mapping.sequences import skips
from calnav.mapping.sequences.readers import Sequence, SequenceConfig, SequenceFrame
from calnav.mapping.sequences.rosbag_camera import Camera, camera_from_info
from calnav.mapping.sequences.rosbag_sync import digest, nearest, stamp_clashes
from calnav.mapping.sequences.rosbag_tf import AMBIGUOUS, NO_SAMPLES, NON_FINITE, NS, PoseTrack, TfTree, frame_name, rigid

TF_TOPIC, TF_STATIC_TOPIC = "/tf", "/tf_static"
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")   # ROS 2 / ROS 1 tf2, and ROS 1 bags of the tf era
INFO_TYPE = "sensor_msgs/msg/CameraInfo"
POSE_TYPES = ("nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/PoseWithCovarianceStamped")
PRESET_KEYS = ("color_topic", "depth_topic", "color_info_topic", "depth_info_topic")   # the topics a preset names
INSTALL_HINT = 'the rosbag layout needs rosbags: pip install -e ".[ros]" (make test installs it into .venv)'


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def open_bag(path: Path):
    """An opened ``rosbags.highlevel.AnyReader`` of ``path``; ValueError (one line) when it is
    missing or not a readable bag (a truncated or damaged file, an unknown storage)."""
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise ValueError(INSTALL_HINT) from None
    if not path.exists():
        raise ValueError(f"rosbag not found: {path}")
    try:   # bags without message definitions (old ROS 2 sqlite3) are read with the latest ROS 2 types
        reader = AnyReader([path], default_typestore=get_typestore(Stores.LATEST))
        reader.open()
    except Exception as exc:   # rosbags' own errors, and sqlite / mcap / struct errors of a damaged file
        raise ValueError(f"{path} is not a readable ROS bag ({type(exc).__name__}: {_one_line(exc)})") from None
    return reader


def _stamp(header) -> int:
    return int(header.stamp.sec) * NS + int(header.stamp.nanosec)


def _pose_sample(msg, msgtype: str) -> tuple[int, np.ndarray, np.ndarray]:
    """(stamp ns, translation (3,), quaternion xyzw (4,)) of a pose message."""
    pose = msg.pose if msgtype == "geometry_msgs/msg/PoseStamped" else msg.pose.pose
    p, q = pose.position, pose.orientation
    return _stamp(msg.header), np.array([p.x, p.y, p.z]), np.array([q.x, q.y, q.z, q.w])


class _Stream:
    """What the opening pass keeps of one image topic: per message (in bag order) its log time
    (ns, for random access), header stamp (ns), pixel digest (``rosbag_sync.digest``); the
    first message, decoded for checks."""

    def __init__(self, topic: str, msgtype: str):
        self.topic, self.msgtype = topic, msgtype
        self.log: list[int] = []
        self.stamps: list[int] = []
        self.digests: list[int] = []
        self.first = None
        self.frame_id = ""


class RosbagSequence(Sequence):
    """An opened (validated) ROS bag; the ``Sequence`` interface (``ids``, ``skipped``,
    ``skips``, ``k_color``, ``k_depth``, ``color_size``, ``depth_size``, ``frames()``,
    ``read(i)``), plus ``topics`` {name: message type}."""

    def __init__(self, root, layout: str = "rosbag", cfg: SequenceConfig | None = None):
        self.root = root = Path(root)
        self.cfg = cfg = cfg or SequenceConfig()
        self.layout = layout
        self._rc = rc = cfg.rosbag
        self._reader = None   # random access (``read``), opened on first use
        self.tf_chain: list[str] = []   # pose_source tf: the frames from the camera up to the fixed frame
        reader = open_bag(root)
        try:
            self.topics = {name: info.msgtype for name, info in reader.topics.items()}
            names = rc.topics()
            self._color = self._image_topic(names.color, ("/compressed",), "color_topic", "colour")
            self._depth = self._image_topic(names.depth, ("/compressedDepth", "/compressed"), "depth_topic", "depth")
            self._semantic = self._image_topic(rc.semantic_topic, (), "semantic_topic", "semantic") \
                if rc.semantic_topic else None
            info_color = self._typed_topic(names.color_info, "color_info_topic", "colour CameraInfo", (INFO_TYPE,))
            info_depth = names.depth_info if self.topics.get(names.depth_info) == INFO_TYPE else info_color
            # the reader's type store, generated from the bag's definitions once, deserialises
            # every later read of this bag (a new reader would generate its code again: ~40 ms)
            store, ros2 = reader.typestore, reader.is2
            self._deserialize = store.deserialize_cdr if ros2 else store.deserialize_ros1
            streams, infos, tf_items, pose_samples = self._scan(reader, info_color, info_depth)
        finally:
            reader.close()
        self._streams = streams
        color, depth = streams[self._color], streams[self._depth]
        self._check_registered(color, depth)
        self.camera_color = self._camera(infos, info_color, color, "colour")
        self.camera_depth = self._camera(infos, info_depth, depth, "depth")
        self.k_color, self.k_depth = self.camera_color.k, self.camera_depth.k
        self.color_size, self.depth_size = self.camera_color.size, self.camera_depth.size
        self._index(tf_items, pose_samples)
        self._has_labels = {"semantic": self._semantic is not None, "label_raw": False}
        self._label_lut = None

    # ------------------------------------------------------------------ opening
    def _topics_text(self) -> str:
        return ", ".join(f"{n} ({t})" for n, t in sorted(self.topics.items())) or "none"

    def _typed_topic(self, name: str, key: str, what: str, types: tuple[str, ...]) -> str:
        if name not in self.topics:
            preset = f", preset {self._rc.preset}" if key in PRESET_KEYS else ""
            raise ValueError(f"{self.root} has no {what} topic {name} (sequence.rosbag.{key}{preset}); its topics: "
                             f"{self._topics_text()}")
        if self.topics[name] not in types:
            raise ValueError(f"{self.root}: {what} topic {name} is {self.topics[name]}; expected {' or '.join(types)}")
        return name

    def _image_topic(self, name: str, suffixes: tuple[str, ...], key: str, what: str) -> str:
        """``name``, else the first ``name + suffix`` (image_transport's compressed topics) the bag has."""
        found = next((t for t in (name, *(name.rstrip("/") + s for s in suffixes)) if t in self.topics), name)
        return self._typed_topic(found, key, f"{what} image", img.IMAGE_TYPES)

    def _scan(self, reader, info_color: str, info_depth: str):
        """One pass over the bag: image headers, the first CameraInfo of each camera, TF, poses."""
        streams = {t: _Stream(t, self.topics[t]) for t in {self._color, self._depth, self._semantic} if t}
        infos: dict[str, object] = {}
        tf_items: dict[str, list] = {TF_TOPIC: [], TF_STATIC_TOPIC: []}
        pose_topic = self._rc.pose_topic if self._rc.pose_source == "topic" else ""
        if pose_topic:
            self._typed_topic(pose_topic, "pose_topic", "pose", POSE_TYPES)
        pose_samples: list = []
        wanted = set(streams) | {info_color, info_depth, pose_topic} | \
            ({TF_TOPIC, TF_STATIC_TOPIC} if self._rc.pose_source == "tf" else set())
        conns = [c for c in reader.connections if c.topic in wanted and
                 (c.topic not in tf_items or c.msgtype in TF_TYPES)]
        topic = ""
        try:
            for conn, log_ns, raw in reader.messages(connections=conns):
                topic = conn.topic
                if topic in streams:
                    s = streams[topic]
                    msg = self._deserialize(raw, conn.msgtype)
                    s.log.append(log_ns)
                    s.stamps.append(_stamp(msg.header))
                    s.digests.append(digest(msg))
                    if s.first is None:
                        s.first, s.frame_id = msg, frame_name(msg.header.frame_id)
                elif topic in (info_color, info_depth):
                    infos.setdefault(topic, self._deserialize(raw, conn.msgtype))
                elif topic in tf_items:
                    for tr in self._deserialize(raw, conn.msgtype).transforms:
                        t, q = tr.transform.translation, tr.transform.rotation
                        tf_items[topic].append((tr.header.frame_id, tr.child_frame_id, _stamp(tr.header),
                                                (t.x, t.y, t.z), (q.x, q.y, q.z, q.w)))
                elif topic == pose_topic:
                    pose_samples.append(_pose_sample(self._deserialize(raw, conn.msgtype), conn.msgtype))
        except Exception as exc:   # a damaged chunk / record / message in the bag
            raise ValueError(f"{self.root}: cannot read the bag at topic {topic or '?'} "
                             f"({type(exc).__name__}: {_one_line(exc)}); is the file truncated?") from None
        for s in streams.values():
            if s.first is None:
                raise ValueError(f"{self.root}: the {s.topic} topic holds no message")
        return streams, infos, tf_items, pose_samples

    def _check_registered(self, color: _Stream, depth: _Stream) -> None:
        if color.frame_id and depth.frame_id and color.frame_id != depth.frame_id and not self._rc.assume_registered:
            raise ValueError(f"{self.root}: depth images ({depth.topic}) are in frame '{depth.frame_id}', colour images "
                             f"in '{color.frame_id}': calnav maps depth registered to the colour camera; record the "
                             "driver's registered depth (sequence.rosbag.preset names it, e.g. RealSense "
                             "/camera/aligned_depth_to_color/image_raw, Azure Kinect /depth_to_rgb/image_raw), or set "
                             "sequence.rosbag.assume_registered=true if this depth is registered under another frame name")

    def _camera(self, infos: dict, info_topic: str, stream: _Stream, what: str) -> Camera:
        """The camera of ``stream`` from its CameraInfo, checked against the first image (decoded)."""
        if info_topic not in infos:
            raise ValueError(f"{self.root}: the {what} CameraInfo topic {info_topic} holds no message")
        try:
            first = self._decode_one(stream, stream.first)
        except ValueError as exc:
            raise ValueError(f"{self.root}: {what} topic {stream.topic}: {exc}") from None
        size = (first.shape[1], first.shape[0])
        try:
            return camera_from_info(infos[info_topic], size)
        except ValueError as exc:
            raise ValueError(f"{self.root}: {what} CameraInfo {info_topic}: {exc}") from None

    def _poses(self, times: np.ndarray, tf_items: dict, pose_samples: list) -> tuple[np.ndarray, np.ndarray]:
        """(poses (m, 4, 4) camera-to-world in OpenCV axes, status (m,): ``rosbag_tf.POSE_OK`` or
        why there is none) at ``times`` (ns)."""
        gap = int(round(self._rc.pose_max_gap_s * NS))
        rc = self._rc
        if rc.pose_source == "topic":
            if not pose_samples:
                raise ValueError(f"{self.root}: the pose topic {rc.pose_topic} holds no message")
            stamps, t, q = zip(*pose_samples)
            poses, status = PoseTrack(stamps, np.array(t), np.array(q)).at(times, gap)
            extrinsic = rigid(np.array(rc.camera_extrinsic[:3])[None], np.array(rc.camera_extrinsic[3:])[None])[0]
            return poses @ extrinsic, status
        camera = rc.camera_frame or self._streams[self._color].frame_id
        if not camera:
            raise ValueError(f"{self.root}: the colour images name no frame (header.frame_id is empty); set "
                             "sequence.rosbag.camera_frame, or use sequence.rosbag.pose_source=topic")
        if not tf_items[TF_TOPIC] and not tf_items[TF_STATIC_TOPIC]:
            raise ValueError(f"{self.root} has no TF (/tf, /tf_static) for the camera poses; its topics: "
                             f"{self._topics_text()}; use sequence.rosbag.pose_source=topic with a pose_topic")
        try:
            tree = TfTree.from_transforms(tf_items[TF_STATIC_TOPIC], tf_items[TF_TOPIC])
            self.tf_chain = tree.chain(camera, rc.fixed_frame)
        except ValueError as exc:
            raise ValueError(f"{self.root}: {exc}") from None
        if all(f in tree.static for f in self.tf_chain[:-1]):   # every frame would get one pose
            raise ValueError(f"{self.root}: the TF chain {' <- '.join(self.tf_chain)} is static (/tf_static only): "
                             f"the camera never moves in '{self.tf_chain[-1]}'; set sequence.rosbag.fixed_frame to the "
                             f"map's frame (TF frames: {', '.join(tree.frames())}) or use pose_source=topic")
        return tree.poses(self.tf_chain, times, gap)

    def _index(self, tf_items: dict, pose_samples: list) -> None:
        """Pair colour with depth (and labels), pose the frames, choose ``ids`` / ``skips``."""
        cfg, rc = self.cfg, self._rc
        tol = int(round(rc.sync_tolerance_s * NS))
        color, depth = self._streams[self._color], self._streams[self._depth]
        c_stamps = np.asarray(color.stamps, np.int64)
        candidates = np.arange(len(c_stamps))[::cfg.frame_stride]
        candidates = candidates[:cfg.max_frames] if cfg.max_frames else candidates
        # the first reason found holds: the colour image itself, then its depth, then its pose
        self.skips = found = skips.SkippedFrames()
        repeat, shared = stamp_clashes(color.stamps, color.digests)
        found.add(candidates[repeat[candidates]], skips.REPEATED)
        found.add(candidates[shared[candidates]], skips.SHARED_STAMP)
        depth_of, has_depth = nearest(depth.stamps, c_stamps[candidates], tol)
        found.add(candidates[~has_depth], skips.no_depth(rc.sync_tolerance_s))
        found.add(candidates[stamp_clashes(depth.stamps, depth.digests)[1][depth_of]], skips.AMBIGUOUS_DEPTH)
        poses, status = self._poses(np.asarray(depth.stamps, np.int64)[depth_of], tf_items, pose_samples)
        for code, reason in ((NON_FINITE, skips.NON_FINITE_POSE), (AMBIGUOUS, skips.AMBIGUOUS_POSE),
                             (NO_SAMPLES, skips.no_pose(rc.pose_max_gap_s))):
            found.add(candidates[status == code], reason)
        keep = ~np.isin(candidates, found.frames)
        self.ids = candidates[keep].tolist()
        if not self.ids:
            raise ValueError(f"{self.root}: no frames to read: {len(candidates)} colour images after frame_stride "
                             f"{cfg.frame_stride} / max_frames {cfg.max_frames}, {found.summary()}")
        self._poses_of = {}
        self._parts: dict[int, list[tuple[str, int]]] = {}
        sem_of = None
        if self._semantic is not None:
            sem_of, has_sem = nearest(self._streams[self._semantic].stamps, c_stamps[self.ids], tol)
            if not has_sem.all():
                raise ValueError(f"{self.root}: {int((~has_sem).sum())} frames have no {self._semantic} image within "
                                 f"{self._rc.sync_tolerance_s:g} s, e.g. frame {self.ids[int(np.argmin(has_sem))]}")
        rows = np.flatnonzero(keep)
        for j, (i, row) in enumerate(zip(self.ids, rows)):
            self._poses_of[i] = _checked_pose(poses[row], i)
            parts = [(self._color, i), (self._depth, int(depth_of[row]))]
            if sem_of is not None:
                parts.append((self._semantic, int(sem_of[j])))
            self._parts[i] = parts

    # ------------------------------------------------------------------ reading
    def _decode_one(self, stream: _Stream, msg) -> np.ndarray:
        if stream.topic == self._color:
            return img.color_rgb(msg, stream.msgtype)
        if stream.topic == self._depth:
            return img.depth_metres(msg, stream.msgtype, self.cfg)
        return img.label_ids(msg, stream.msgtype)

    def _frame(self, index: int, msgs: dict) -> SequenceFrame:
        """Frame ``index`` from its deserialised messages {(topic, ordinal): message}."""
        out = {}
        for (topic, ordinal), msg in ((key, msgs[key]) for key in self._parts[index]):
            stream = self._streams[topic]
            try:
                out[topic] = self._decode_one(stream, msg)
            except ValueError as exc:
                raise ValueError(f"{self.root}: frame {index}: {topic} message {ordinal}: {exc}") from None
            cam = self.camera_color if topic != self._depth else self.camera_depth
            shape = out[topic].shape[1::-1]
            if shape != cam.size:
                raise ValueError(f"{self.root}: frame {index}: {topic} image is {shape[0]}x{shape[1]}, the topic's first is "
                                 f"{cam.size[0]}x{cam.size[1]}")
            out[topic] = cam.undistort(out[topic], nearest=topic != self._color)
        sem = out.get(self._semantic) if self._semantic is not None else None
        return SequenceFrame(index, out[self._color], out[self._depth], self.k_color, self.k_depth,
                             self._poses_of[index], sem)

    def frames(self) -> Iterator[SequenceFrame]:
        """The frames of ``ids`` in order, from one pass over the bag (a message is held only
        until the frames that use it are decoded)."""
        uses: dict[tuple[str, int], int] = {}
        for i in self.ids:
            for key in self._parts[i]:
                uses[key] = uses.get(key, 0) + 1
        reader = open_bag(self.root)
        try:
            conns = [c for c in reader.connections if c.topic in self._streams]
            count = dict.fromkeys(self._streams, 0)
            held: dict[tuple[str, int], object] = {}
            pending = iter(self.ids)
            nxt = next(pending, None)
            messages = reader.messages(connections=conns)
            while nxt is not None:
                try:
                    conn, _, raw = next(messages)
                    key = (conn.topic, count[conn.topic])
                    count[conn.topic] += 1
                    if key in uses:
                        held[key] = self._deserialize(raw, conn.msgtype)
                except StopIteration:
                    raise ValueError(f"{self.root}: the bag ended before frame {nxt}'s messages") from None
                except Exception as exc:
                    raise ValueError(f"{self.root}: cannot read the bag before frame {nxt} "
                                     f"({type(exc).__name__}: {_one_line(exc)}); is the file truncated?") from None
                while nxt is not None and all(k in held for k in self._parts[nxt]):
                    frame = self._frame(nxt, held)
                    for k in self._parts[nxt]:
                        uses[k] -= 1
                        if not uses[k]:
                            del held[k]
                    yield frame
                    nxt = next(pending, None)
        finally:
            reader.close()

    def pose_of(self, index: int) -> np.ndarray:
        return self._poses_of[index]

    def read(self, index: int) -> SequenceFrame:
        """Frame ``index`` (one of ``ids``), by random access (its messages' log times)."""
        if self._reader is None:
            self._reader = open_bag(self.root)
        msgs = {}
        for topic, ordinal in self._parts[index]:
            log = self._streams[topic].log
            rank = ordinal - log.index(log[ordinal])   # messages of the topic logged at the same ns before it
            conns = [c for c in self._reader.connections if c.topic == topic]
            found = list(self._reader.messages(connections=conns, start=log[ordinal], stop=log[ordinal] + 1))
            conn, _, raw = found[rank]
            msgs[(topic, ordinal)] = self._deserialize(raw, conn.msgtype)
        return self._frame(index, msgs)

    def check_scale(self, depth_min_m: float, depth_max_m: float, voxel_size_m: float) -> None:
        """As ``Sequence.check_scale``; its sampled reads open the random-access reader, which is
        closed again (a command that maps many bags would otherwise hold one file per bag)."""
        try:
            super().check_scale(depth_min_m, depth_max_m, voxel_size_m)
        finally:
            self.close()

    def close(self) -> None:
        """Close the random-access reader (``read``), if open."""
        if self._reader is not None:
            self._reader.close()
            self._reader = None

    def labelled_ply(self) -> Path | None:
        """The ground-truth mesh inside a ROS 2 bag directory (as ``Sequence``); None for a bag file."""
        return super().labelled_ply() if self.root.is_dir() else None


def _checked_pose(pose: np.ndarray, index: int) -> np.ndarray:
    from calnav.mapping import frame_geometry as fg

    try:
        return fg.check_pose(pose)
    except ValueError as exc:
        raise ValueError(f"frame {index}: {exc}") from None
