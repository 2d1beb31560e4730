"""Colour and depth frames paired by exact stamp (what message_filters' exact-time synchronizer
does; it is not available from PyPI).

Each stream arrives in stamp order (one writer, one reader), but either may lose a frame: a
reliable keep-last subscription overwrites a sample the node has not taken yet. A frame whose
partner was lost must not wait for it: once one stream has delivered stamp S, no frame of the
other stream stamped S or earlier waits any more, since its partner has come or never will.
(Dropped only for the buffer's capacity, such frames used to pile up to it, 1-2 MB each, and
the perception node's memory crept up by 15-20 MB over a few minutes.) When a stream's clock
goes back (a restarted simulator), its waiting frames are dropped, and the first frame of the
new timeline may be lost.
"""

from __future__ import annotations

from typing import Generic, TypeVar

Frame = TypeVar("Frame")


class ExactStampPairer(Generic[Frame]):
    """Pairs frames of two streams (0 and 1) that carry the same stamp (integer nanoseconds)."""

    def __init__(self, capacity: int) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be at least 1, got {capacity}")
        self.capacity = capacity
        # Per stream: stamp -> frame waiting for its partner, in arrival order.
        self._waiting: tuple[dict[int, Frame], dict[int, Frame]] = ({}, {})
        self._latest: list[int | None] = [None, None]   # newest stamp each stream delivered

    def waiting(self, stream: int) -> list[int]:
        """Stamps of the frames of `stream` that wait for a partner, in arrival order."""
        return list(self._waiting[stream])

    def add(self, stream: int, stamp: int, frame: Frame) -> tuple[Frame, Frame] | None:
        """Offer a frame of `stream`; returns (stream 0's frame, stream 1's frame) when it
        completes a pair, else None."""
        if stream not in (0, 1):
            raise ValueError(f"stream must be 0 or 1, got {stream}")
        own, other = self._waiting[stream], self._waiting[1 - stream]
        latest = self._latest[stream]
        if latest is not None and stamp < latest:
            # The stream's clock went back (a restarted simulator): its old frames never pair.
            own.clear()
        self._latest[stream] = stamp
        _drop_older(other, stamp)
        partner = other.pop(stamp, None)
        if partner is None:
            other_latest = self._latest[1 - stream]
            if other_latest is not None and stamp <= other_latest:
                return None                 # the other stream has passed this stamp
            own[stamp] = frame
            while len(own) > self.capacity:
                del own[next(iter(own))]
            return None
        # nothing of `own` older than `stamp` waits: the other stream, at or past `stamp`,
        # has passed it (the rule above)
        return (frame, partner) if stream == 0 else (partner, frame)


def _drop_older(waiting: dict[int, Frame], stamp: int) -> None:
    for old in [s for s in waiting if s < stamp]:
        del waiting[old]
