"""The tracker's queue of frame infos: order, the live source's staleness rule (at most
``max_lag_frames`` behind), the end of stream, malformed infos, and the file source's "skip nothing"."""

import logging

import pytest

from common.msgs import FrameInfo
from services.bus import Counters, Inbox, Stopper
from services.frame_infos import InfoQueue

log = logging.getLogger("test")


class _Payload:
    def __init__(self, data: bytes):
        self.data = data

    def to_bytes(self) -> bytes:
        return self.data


class _Sample:
    def __init__(self, data: bytes):
        self.payload = _Payload(data)


def _queue(skip_stale: bool, max_lag: int, infos: list) -> tuple[InfoQueue, Counters, callable]:
    inbox, c = Inbox(), Counters("tracker")
    put = inbox.callback("info")
    for item in infos:
        put(_Sample(item if isinstance(item, bytes) else item.SerializeToString()))
    return InfoQueue(inbox, skip_stale, max_lag, c, log), c, put


def _take_all(q: InfoQueue) -> list[tuple[int, bool, int]]:
    out, stopper = [], Stopper()
    while True:
        info, skipped = q.next(stopper, timeout=0.01)
        if info is None:
            return out
        out.append((info.index, info.end_of_stream, skipped))


def _frames(n: int, eos: bool = False) -> list[FrameInfo]:
    infos = [FrameInfo(index=i, time_s=i / 30, width=1280, height=720) for i in range(n)]  # (checked: a size)
    return infos + ([FrameInfo(index=n, end_of_stream=True)] if eos else [])


def test_live_source_keeps_at_most_max_lag_frames_waiting():
    """12 frames waiting with a lag of 4: the 7 oldest are stale (skipped at once, counted),
    the 5 newest are tracked in order."""
    q, c, _ = _queue(True, 4, _frames(12))
    taken = _take_all(q)
    assert [t[0] for t in taken] == [7, 8, 9, 10, 11]
    assert taken[0][2] == 7 and all(t[2] == 0 for t in taken[1:])
    assert c["dropped"] == 7 and c["received"] == 12


def test_frames_arriving_while_tracking_are_caught_up_in_order():
    """A slow step lets 3 frames pile up behind: within the lag they are all tracked, in order."""
    q, c, put = _queue(True, 4, _frames(1))
    stopper = Stopper()
    info, _ = q.next(stopper, 0.01)
    assert info.index == 0
    for f in _frames(4)[1:]:
        put(_Sample(f.SerializeToString()))
    assert [t[0] for t in _take_all(q)] == [1, 2, 3] and c["dropped"] == 0


def test_lag_zero_jumps_to_the_newest():
    q, c, _ = _queue(True, 0, _frames(5))
    assert _take_all(q) == [(4, False, 4)] and c["dropped"] == 4


def test_file_source_skips_nothing():
    q, c, _ = _queue(False, 0, _frames(20))
    assert [t[0] for t in _take_all(q)] == list(range(20)) and c["dropped"] == 0


def test_end_of_stream_is_never_skipped_and_frames_before_it_are_tracked():
    q, c, _ = _queue(True, 2, _frames(6, eos=True))
    taken = _take_all(q)
    assert taken[-1][:2] == (6, True)
    assert [t[0] for t in taken[:-1]] == [4, 5] and c["dropped"] == 4


def test_malformed_info_is_counted_and_the_next_one_taken():
    q, c, _ = _queue(True, 8, [_frames(1)[0], b"\xff\x00garbage", FrameInfo(index=1, width=1280, height=720)])
    assert [t[0] for t in _take_all(q)] == [0, 1]
    assert c["malformed"] == 1 and c["received"] == 2


def test_negative_lag_is_refused():
    with pytest.raises(ValueError, match="max_lag_frames"):
        _queue(True, -1, [])


def test_lag_budget_defaults_by_mode():
    """Single-target filters keep up on average and get a lag budget; the multi-target ones, slower
    than the frame rate, always take the newest frame; an explicit value wins."""
    from services.tracker import TrackerServiceSettings

    assert TrackerServiceSettings(init_box=(1, 2, 3, 4)).lag_frames() == 14
    assert TrackerServiceSettings(multi="{}").lag_frames() == 0
    assert TrackerServiceSettings(init_box=(1, 2, 3, 4), max_lag_frames=3).lag_frames() == 3
    with pytest.raises(ValueError):
        TrackerServiceSettings(init_box=(1, 2, 3, 4), max_lag_frames=-1)


def test_infos_a_tracker_cannot_step_on_are_dropped_and_counted():
    """NaN or backward time, an old index replayed, a 1e6 s jump, a zero homography: each dropped
    and counted (each had raised in Tracker.step or thrown the estimate 1e7 px off)."""
    bad = [FrameInfo(index=2, time_s=float("nan"), width=1280, height=720),
           FrameInfo(index=0, time_s=0.0, width=1280, height=720),
           FrameInfo(index=2, time_s=1e6, width=1280, height=720),
           FrameInfo(index=2, time_s=0.01, width=1280, height=720)]
    zero = FrameInfo(index=2, time_s=2 / 30, width=1280, height=720)
    zero.homography.extend([0.0] * 9)
    q, c, _ = _queue(False, 14, _frames(2) + bad + [zero] + [FrameInfo(index=2, time_s=2 / 30, width=1280, height=720)])
    assert [t[0] for t in _take_all(q)] == [0, 1, 2]
    assert c["malformed"] == 5 and c["received"] == 3
    assert q.guard.rejects.snapshot() == {"frame/info": {"bad_time": 1, "index_not_increasing": 1, "time_jump": 1,
                                                         "time_backwards": 1, "bad_homography": 1}}
