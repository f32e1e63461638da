"""``prefetched``: an iterator's items produced by a background thread a bounded number ahead
(frame decoding overlapping fusion: ``calnav map``, the recorded-sequence source of
``calnav calibrate-map --sequences``)."""
from __future__ import annotations

import queue
import threading
from typing import Iterable, Iterator

PREFETCH_FRAMES = 2     # frames decoded ahead of the map (bounded: memory does not grow with the recording)


def prefetched(items: Iterable, depth: int = PREFETCH_FRAMES) -> Iterator:
    """``items`` produced by a background thread at most ``depth`` ahead (image decoding and
    Open3D release the GIL, so decoding overlaps fusion); exceptions are re-raised here."""
    q: queue.Queue = queue.Queue(maxsize=depth)
    done = object()
    stop = threading.Event()

    def work():
        try:
            for item in items:
                if stop.is_set():
                    return
                q.put((True, item))
            q.put((True, done))
        except BaseException as exc:   # re-raised in the consumer
            q.put((False, exc))

    thread = threading.Thread(target=work, daemon=True)
    thread.start()
    try:
        while True:
            ok, item = q.get()
            if not ok:
                raise item
            if item is done:
                return
            yield item
    finally:
        stop.set()
        while thread.is_alive():   # unblock a producer waiting on a full queue
            try:
                q.get_nowait()
            except queue.Empty:
                thread.join(0.01)
