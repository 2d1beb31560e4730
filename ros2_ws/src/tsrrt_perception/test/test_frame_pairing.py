"""Exact-stamp pairing of colour and depth: pairs in either arrival order, and no frame whose
partner was lost is kept once it can no longer be paired."""

import numpy as np
import pytest

from tsrrt_perception.frame_pairing import ExactStampPairer

COLOUR, DEPTH = 0, 1


def test_pairs_in_either_order():
    pairer = ExactStampPairer(10)
    assert pairer.add(COLOUR, 1, "c1") is None
    assert pairer.add(DEPTH, 1, "d1") == ("c1", "d1")
    assert pairer.add(DEPTH, 2, "d2") is None
    assert pairer.add(COLOUR, 2, "c2") == ("c2", "d2")
    assert pairer.waiting(COLOUR) == pairer.waiting(DEPTH) == []


def test_a_frame_whose_partner_was_lost_is_dropped():
    pairer = ExactStampPairer(10)
    pairer.add(DEPTH, 1, "d1")                  # colour 1 lost
    pairer.add(DEPTH, 2, "d2")
    assert pairer.add(COLOUR, 2, "c2") == ("c2", "d2")
    assert pairer.waiting(DEPTH) == []          # d1 can never pair: colour has passed stamp 1
    pairer.add(COLOUR, 3, "c3")                 # depth 3 lost
    assert pairer.add(DEPTH, 4, "d4") is None
    assert pairer.waiting(COLOUR) == [] and pairer.waiting(DEPTH) == [4]


def test_one_stream_running_ahead_keeps_its_frames():
    pairer = ExactStampPairer(10)
    for stamp in range(1, 6):
        assert pairer.add(COLOUR, stamp, f"c{stamp}") is None
    assert pairer.add(DEPTH, 3, "d3") == ("c3", "d3")
    assert pairer.waiting(COLOUR) == [4, 5]     # they may still get their depth
    assert pairer.add(DEPTH, 4, "d4") == ("c4", "d4")


def test_random_losses_leave_waiting_only_frames_the_other_stream_has_not_passed():
    """Two in-order streams of 2,000 stamps, each frame lost with probability 0.2 and arriving
    up to three frame periods late: every pair whose frames both arrive is made, and frames
    left waiting are only those the other stream has not passed yet."""
    rng = np.random.default_rng(7)
    stamps = np.arange(2000)
    delivered = [stamps[rng.random(stamps.size) > 0.2] for _ in (COLOUR, DEPTH)]
    arrival_times = [np.maximum.accumulate(d + rng.uniform(0, 3, d.size)) for d in delivered]
    arrivals = sorted([(float(t), stream, int(s)) for stream in (COLOUR, DEPTH)
                       for s, t in zip(delivered[stream], arrival_times[stream], strict=True)])
    pairer = ExactStampPairer(10)
    paired, latest = [], [-1, -1]
    for _, stream, stamp in arrivals:
        pair = pairer.add(stream, stamp, (stream, stamp))
        latest[stream] = stamp
        if pair is not None:
            assert pair[0] == (COLOUR, stamp) and pair[1] == (DEPTH, stamp)
            paired.append(stamp)
        for waiting_stream in (COLOUR, DEPTH):
            assert all(s > latest[1 - waiting_stream] for s in pairer.waiting(waiting_stream))
    assert paired == sorted(set(delivered[COLOUR]) & set(delivered[DEPTH]))


def test_capacity_drops_the_longest_waiting():
    pairer = ExactStampPairer(3)
    for stamp in range(1, 6):
        pairer.add(COLOUR, stamp, f"c{stamp}")
    assert pairer.waiting(COLOUR) == [3, 4, 5]
    assert pairer.add(DEPTH, 2, "d2") is None   # c2 was dropped for capacity
    assert pairer.add(DEPTH, 3, "d3") == ("c3", "d3")


def test_a_clock_that_goes_back_starts_over():
    """A restarted simulator stamps from zero again: the old timeline's frames never pair, and
    the new timeline's pair from its second stamp on."""
    pairer = ExactStampPairer(10)
    pairer.add(COLOUR, 100, "old c100")
    pairer.add(DEPTH, 101, "old d101")
    pairer.add(COLOUR, 1, "c1")
    pairer.add(DEPTH, 1, "d1")
    assert pairer.waiting(COLOUR) == pairer.waiting(DEPTH) == []
    assert pairer.add(COLOUR, 2, "c2") is None
    assert pairer.add(DEPTH, 2, "d2") == ("c2", "d2")


@pytest.mark.parametrize("stream, capacity", [(2, 10), (COLOUR, 0)])
def test_bad_arguments_are_named(stream, capacity):
    with pytest.raises(ValueError, match="stream|capacity"):
        ExactStampPairer(capacity).add(stream, 1, "x")
