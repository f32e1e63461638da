"""Messages of a ROS bag matched by header stamp: the nearest stamp within a tolerance
(``nearest``: colour to depth, colour to labels) and the messages of one topic that share a
stamp (``stamp_clashes``): a repeat of an earlier message (same stamp, same pixels) or two
different messages at one stamp. Stamps are integer nanoseconds; a message's digest is the
CRC-32 of its pixel bytes (``digest``)."""
from __future__ import annotations

import zlib

import numpy as np


def digest(msg) -> int:
    """CRC-32 of an image message's pixel bytes (``data``; raw or compressed), for telling a repeated
    message from another one at the same stamp (a ROS 1 header's ``seq`` is left out: a recorder
    that publishes a message again numbers it anew)."""
    return zlib.crc32(np.ascontiguousarray(msg.data).view(np.uint8))


def nearest(stamps, query: np.ndarray, tol_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """(index into ``stamps`` (n,) of the nearest stamp to each ``query`` (m,), found within
    ``tol_ns``), both (m,); of equal stamps the first recorded."""
    s = np.asarray(stamps, np.int64)
    order = np.argsort(s, kind="stable")
    sorted_s = s[order]
    hi = np.clip(np.searchsorted(sorted_s, query), 0, len(s) - 1)
    lo = np.clip(hi - 1, 0, len(s) - 1)
    pick = np.where(np.abs(sorted_s[lo] - query) <= np.abs(sorted_s[hi] - query), lo, hi)
    return order[pick], np.abs(sorted_s[pick] - query) <= tol_ns


def stamp_clashes(stamps, digests) -> tuple[np.ndarray, np.ndarray]:
    """(repeat (n,) bool: the message repeats an earlier one of its stamp, pixel for pixel;
    shared (n,) bool: its stamp holds another message of other pixels) of one topic's messages,
    ``stamps`` and ``digests`` (n,) in bag order. A stamp's messages are either all repeats of its
    first (the first is kept) or all shared (none can be told from the others)."""
    s, d = np.asarray(stamps, np.int64), np.asarray(digests, np.int64)
    repeat, shared = np.zeros(len(s), bool), np.zeros(len(s), bool)
    order = np.argsort(s, kind="stable")
    steps = np.diff(s[order])
    if steps.all():   # every stamp once: the usual recording
        return repeat, shared
    for group in np.split(order, np.flatnonzero(steps) + 1):
        if len(group) < 2:
            continue
        if (d[group] == d[group[0]]).all():
            repeat[group[1:]] = True
        else:
            shared[group] = True
    return repeat, shared
