"""Frames of a recording left out of its map, each with its reason (``SkippedFrames``): the one
rule every reader (folder layouts, ROS 1 / ROS 2 bags, mcap) goes through, so a frame is
skipped, counted and reported the same way whatever it was recorded in.

A frame is skipped, never guessed at, when its data is not one thing: a non-finite pose (a
folder's ``-inf`` rows, a bag's NaN TF / odometry sample at its stamp or one its pose would be
interpolated across), no pose, no depth image, a stamp shared with another, different image (which
pose belongs to which image is unknown), a repeat of the message before it, two different depth
images or pose samples at the stamp it is read at. ``calnav map`` and ``calnav replay`` write
``skipped_frames`` (frame numbers) and ``skip_reasons`` ({reason: frame numbers}) and print
``summary()``.
"""
from __future__ import annotations

NON_FINITE_POSE = "a non-finite pose (NaN / inf: the tracker lost itself)"
SHARED_STAMP = "a stamp shared with another, different colour image (which pose is whose is unknown)"
REPEATED = "a repeat of an earlier message (the same stamp and pixels)"
AMBIGUOUS_DEPTH = "two different depth images at its depth stamp"
AMBIGUOUS_POSE = "two different pose samples at a stamp its pose is read from"


def no_depth(tolerance_s: float) -> str:
    """A bag's colour image without a depth image within ``tolerance_s`` seconds."""
    return f"no depth image within {tolerance_s:g} s (sequence.rosbag.sync_tolerance_s)"


def no_pose(max_gap_s: float) -> str:
    """A bag's frame whose stamp has no pose samples around it at most ``max_gap_s`` apart."""
    return (f"no pose (the pose samples around it more than {max_gap_s:g} s apart, or none; "
            "sequence.rosbag.pose_max_gap_s)")


class SkippedFrames:
    """Frame number -> why it is left out (``reasons``; the first reason given to a frame holds)."""

    def __init__(self) -> None:
        self.reasons: dict[int, str] = {}

    def add(self, frames, reason: str) -> None:
        """Skip each of ``frames`` (frame numbers) for ``reason`` unless it is skipped already."""
        for i in frames:
            self.reasons.setdefault(int(i), reason)

    def __contains__(self, index: int) -> bool:
        return index in self.reasons

    def __len__(self) -> int:
        return len(self.reasons)

    @property
    def frames(self) -> list[int]:
        """The skipped frame numbers, in order."""
        return sorted(self.reasons)

    def by_reason(self) -> dict[str, list[int]]:
        """{reason: frame numbers in order}, reasons in the order first given."""
        out: dict[str, list[int]] = {r: [] for r in self.reasons.values()}
        for i in self.frames:
            out[self.reasons[i]].append(i)
        return out

    def summary(self) -> str:
        """One line for the command's report: "1 with a non-finite pose (...), 2 with ..."."""
        return ", ".join(f"{len(v)} with {k}" for k, v in self.by_reason().items()) or "none"
