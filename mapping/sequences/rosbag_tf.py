"""Rigid transforms of a ROS bag over time: a time series of one transform (``PoseTrack``,
interpolated: linear translation, quaternion slerp with scipy's ``Slerp``) and the TF tree
(``TfTree``: ``/tf_static`` edges constant, ``/tf`` edges tracks) with the chain from a fixed
frame to a camera frame.

Times are integer nanoseconds (ROS stamps); a pose is (4, 4) float64 child-to-parent, i.e. the
child frame's pose in the parent frame (``geometry_msgs/Transform`` of a ``TransformStamped``
whose header names the parent). Frame names are compared without a leading ``/`` (tf2 drops it;
ROS 1 tf wrote ``/base_link``).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

NS = 1_000_000_000   # nanoseconds per second
MIN_QUAT_NORM = 1e-9   # a quaternion shorter than this has no direction: no rotation


def frame_name(name: str) -> str:
    """A TF frame name as tf2 compares it (no leading '/')."""
    return name.lstrip("/")


def rigid(translation: np.ndarray, quat_xyzw: np.ndarray) -> np.ndarray:
    """(..., 4, 4) float64 transforms of (..., 3) translations and (..., 4) quaternions (x, y, z,
    w: ROS order; normalised by scipy)."""
    translation = np.asarray(translation, np.float64)
    out = np.zeros(translation.shape[:-1] + (4, 4))
    out[..., :3, :3] = Rotation.from_quat(np.asarray(quat_xyzw, np.float64).reshape(-1, 4)).as_matrix().reshape(
        translation.shape[:-1] + (3, 3))
    out[..., :3, 3] = translation
    out[..., 3, 3] = 1.0
    return out


# why a time has no pose (``PoseTrack.at``, ``TfTree.poses``); 0 = it has one
POSE_OK, NO_SAMPLES, NON_FINITE, AMBIGUOUS = 0, 1, 2, 3


class PoseTrack:
    """One transform over time: samples at increasing stamps (ns); ``at(times)`` interpolates
    between the two samples around each time when they are at most ``max_gap_ns`` apart (a time
    equal to a sample's stamp takes that sample as it is); other times have no pose. A sample
    that is no rigid transform (NaN / inf, a zero quaternion: a tracker that lost itself) gives
    no pose at its stamp nor across it (``NON_FINITE``), as a folder's non-finite pose gives its
    frame none; a stamp holding two different samples gives none at or across it
    (``AMBIGUOUS``: which is right is unknown); a sample repeated as it was counts once."""

    def __init__(self, stamps_ns, translations, quats_xyzw):
        stamps = np.asarray(stamps_ns, np.int64).reshape(-1)
        t = np.asarray(translations, np.float64).reshape(-1, 3)
        q = np.asarray(quats_xyzw, np.float64).reshape(-1, 4)
        good = np.isfinite(t).all(axis=1) & np.isfinite(q).all(axis=1) & (np.linalg.norm(q, axis=1) > MIN_QUAT_NORM)
        self.dropped = int((~good).sum())
        self.non_finite = np.unique(stamps[~good])   # stamps of the samples that are no rigid transform
        order = np.argsort(stamps[good], kind="stable")
        stamps, t, q = stamps[good][order], t[good][order], q[good][order]
        # one sample per stamp (Slerp needs strictly increasing times); a stamp whose samples differ is ambiguous
        values = np.hstack([t, q])
        first = np.append(True, stamps[1:] != stamps[:-1]) if len(stamps) else np.zeros(0, bool)
        group = np.cumsum(first) - 1
        differs = np.zeros(int(first.sum()), bool)
        np.logical_or.at(differs, group, (values != values[np.flatnonzero(first)][group]).any(axis=1))
        self.ambiguous = stamps[first][differs]
        keep = first.copy()
        keep[np.flatnonzero(first)[differs]] = False
        self.stamps, self.translations = stamps[keep], t[keep]
        self.rotations = Rotation.from_quat(q[keep]) if len(self.stamps) else None
        t0 = self.stamps[0] if len(self.stamps) else 0
        self._slerp = Slerp((self.stamps - t0) / NS, self.rotations) if len(self.stamps) >= 2 else None
        self._t0 = t0

    def __len__(self) -> int:
        return len(self.stamps)

    def at(self, times_ns: np.ndarray, max_gap_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """(poses (m, 4, 4), status (m,) int: ``POSE_OK``, or why there is none: ``NO_SAMPLES``,
        ``NON_FINITE``, ``AMBIGUOUS``) at ``times_ns`` (m,); poses without one are identity."""
        times = np.asarray(times_ns, np.int64)
        n = len(self.stamps)
        poses = np.broadcast_to(np.eye(4), (len(times), 4, 4)).copy()
        status = np.full(len(times), NO_SAMPLES, np.int64)
        if n:
            i0 = np.searchsorted(self.stamps, times, side="right") - 1
            exact = (i0 >= 0) & (self.stamps[np.clip(i0, 0, n - 1)] == times)
            inside = (i0 >= 0) & (i0 + 1 < n)
            i0c, i1c = np.clip(i0, 0, n - 1), np.clip(i0 + 1, 0, n - 1)
            interp = inside & ~exact & (self.stamps[i1c] - self.stamps[i0c] <= max_gap_ns)
            if exact.any():
                poses[exact, :3, :3] = self.rotations[i0c[exact]].as_matrix()
                poses[exact, :3, 3] = self.translations[i0c[exact]]
            if interp.any():
                a, b = i0c[interp], i1c[interp]
                frac = ((times[interp] - self.stamps[a]) / (self.stamps[b] - self.stamps[a]))[:, None]
                poses[interp, :3, 3] = self.translations[a] * (1.0 - frac) + self.translations[b] * frac
                poses[interp, :3, :3] = self._slerp((times[interp] - self._t0) / NS).as_matrix()
            status[exact | interp] = POSE_OK
            # the span a pose is read from: the time itself, or the two samples it is interpolated between
            lo = np.where(interp, self.stamps[i0c], times)
            hi = np.where(interp, self.stamps[i1c], times)
        else:
            lo = hi = times
        for code, bad in ((AMBIGUOUS, self.ambiguous), (NON_FINITE, self.non_finite)):
            if len(bad):   # a bad sample inside the span (or at the time itself, where no pose is left)
                hit = np.searchsorted(bad, lo, side="left") < np.searchsorted(bad, hi, side="right")
                status[hit] = code
        poses[status != POSE_OK] = np.eye(4)
        return poses, status


@dataclass
class TfTree:
    """The TF tree of a bag: per child frame its parent and either a constant transform
    (``/tf_static``) or a ``PoseTrack`` (``/tf``)."""

    static: dict[str, tuple[str, np.ndarray]] = field(default_factory=dict)
    dynamic: dict[str, tuple[str, PoseTrack]] = field(default_factory=dict)

    @classmethod
    def from_transforms(cls, static: list, dynamic: list) -> "TfTree":
        """From (parent, child, stamp_ns, translation (3,), quaternion xyzw (4,)) tuples of
        ``/tf_static`` and ``/tf``; ValueError (one line) for a frame with two parents."""
        tree = cls()
        parents: dict[str, tuple[str, str]] = {}
        for topic, items in (("/tf_static", static), ("/tf", dynamic)):
            for parent, child, *_ in items:
                parent, child = frame_name(parent), frame_name(child)
                seen = parents.setdefault(child, (parent, topic))
                if seen[0] == parent and seen[1] != topic:
                    raise ValueError(f"TF frame '{child}' is published on both /tf_static and /tf; a frame's "
                                     "transform is either static or moving")
                if seen != (parent, topic):
                    raise ValueError(f"TF frame '{child}' has two parents: '{seen[0]}' ({seen[1]}) and '{parent}' "
                                     f"({topic}); a TF tree gives each frame one parent")
        for parent, child, _, t, q in static:   # the last static transform of a frame holds
            tree.static[frame_name(child)] = (frame_name(parent), rigid(np.asarray(t)[None], np.asarray(q)[None])[0])
        grouped: dict[str, list] = {}
        for parent, child, stamp, t, q in dynamic:
            grouped.setdefault(frame_name(child), []).append((stamp, t, q))
        for child, samples in grouped.items():
            stamps, t, q = zip(*samples)
            tree.dynamic[child] = (parents[child][0], PoseTrack(stamps, np.array(t), np.array(q)))
        return tree

    def parent(self, frame: str) -> str | None:
        if frame in self.static:
            return self.static[frame][0]
        if frame in self.dynamic:
            return self.dynamic[frame][0]
        return None

    def frames(self) -> list[str]:
        """Every frame named in the tree, sorted."""
        names = set(self.static) | set(self.dynamic)
        names |= {p for p, _ in self.static.values()} | {p for p, _ in self.dynamic.values()}
        return sorted(names)

    def chain(self, camera: str, fixed: str = "") -> list[str]:
        """Frames from ``camera`` up to ``fixed`` (both included; ``fixed`` "" = the root above
        ``camera``); ValueError naming the frames when ``fixed`` is not above ``camera``."""
        camera, fixed = frame_name(camera), frame_name(fixed)
        if camera not in self.frames():
            known = ", ".join(self.frames()) or "none"
            raise ValueError(f"the camera frame '{camera}' is in no transform of /tf or /tf_static (TF frames: {known})")
        path = [camera]
        while path[-1] != fixed and (up := self.parent(path[-1])) is not None:
            if up in path:
                raise ValueError(f"the TF tree has a cycle: {' <- '.join([*path, up])}")
            path.append(up)
        if fixed and path[-1] != fixed:
            raise ValueError(f"broken TF chain: no transform path from '{fixed}' to '{camera}'; the chain from the camera "
                             f"ends at '{path[-1]}' ({' <- '.join(path)}); TF frames: {', '.join(self.frames())}")
        return path

    def poses(self, path: list[str], times_ns: np.ndarray, max_gap_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """(poses (m, 4, 4) of ``path[0]`` in ``path[-1]``, status (m,) int as ``PoseTrack.at``'s:
        the worst of the chain's edges) at ``times_ns``."""
        times = np.asarray(times_ns, np.int64)
        poses = np.broadcast_to(np.eye(4), (len(times), 4, 4)).copy()
        status = np.full(len(times), POSE_OK, np.int64)
        for child in path[:-1]:   # camera upwards: pose_parent = T_parent_child @ pose_child
            if child in self.static:
                poses = self.static[child][1] @ poses
                continue
            edge, why = self.dynamic[child][1].at(times, max_gap_ns)
            poses = edge @ poses
            status = np.maximum(status, why)
        return poses, status
