"""Ingest, paced by the consumer, holds a file's next frame while a detector that was on the bus
is gone (being restarted): a frame sent meanwhile could only be predicted, and a source that went
on would send the rest of the file in milliseconds. In-process ingest on a loopback bus; the test
plays the tracker (an estimate for each frame) and the detector's liveliness token."""

from __future__ import annotations

import signal
import threading
import time

import pytest

from common.msgs import Estimate, FrameInfo
from services import ingest
from services.bus import BusConfig, Inbox, Stopper, open_session, payload_bytes
from services.launcher import free_ports

FRAMES = 14
GONE_AT = 4  # the detector's token leaves once this frame is estimated
GAP_S = 1.5  # and a new one comes this much later


def run(detector_wait_s: float, with_detector: bool):
    """Ingest over FRAMES synthetic frames; the frames' arrival times, and when the detector's
    token went and came back."""
    port = free_ports(1)[0]
    cfg = ingest.IngestSettings(source="synthetic:0", frames=FRAMES, pace="consumer",
                                detector_wait_s=detector_wait_s, wait_for=["tracker"])
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    stopper = Stopper()
    result: dict = {}
    ingest_thread = threading.Thread(
        target=lambda: result.setdefault("counters", ingest.serve(
            BusConfig(stream="hold", listen=[f"tcp/127.0.0.1:{port}"]), cfg, stopper)), daemon=True)
    arrived: dict[int, float] = {}
    gone = back = None
    try:
        with open_session(BusConfig(stream="hold", connect=[f"tcp/127.0.0.1:{port}"])) as s:
            token = s.liveliness().declare_token("polartrack/hold/alive/detector") if with_detector else None
            inbox = Inbox()
            s.declare_subscriber("polartrack/hold/frame/info", inbox.callback("info"))
            pub = s.declare_publisher("polartrack/hold/track/estimate")
            tracker = s.liveliness().declare_token("polartrack/hold/alive/tracker")  # ingest waits for it
            ingest_thread.start()
            deadline = time.monotonic() + 120
            ended = False
            while not ended and time.monotonic() < deadline:
                inbox.wait(0.05)
                now = time.monotonic()
                if gone is not None and back is None and now - gone >= GAP_S:
                    token = s.liveliness().declare_token("polartrack/hold/alive/detector")  # a new one
                    back = now
                while (sample := inbox.pop("info")) is not None:
                    info = FrameInfo.FromString(payload_bytes(sample))
                    if info.end_of_stream:
                        ended = True
                        break
                    arrived[info.index] = time.monotonic()
                    pub.put(Estimate(frame_index=info.index).SerializeToString())
                    if info.index == GONE_AT and token is not None and gone is None:
                        token.undeclare()
                        gone = time.monotonic()
            ingest_thread.join(30)
            if token is not None and back is not None:
                token.undeclare()
            tracker.undeclare()
    finally:
        stopper.event.set()
        ingest_thread.join(10)
        for sig, h in handlers.items():
            signal.signal(sig, h)
    assert not ingest_thread.is_alive()
    assert sorted(arrived) == list(range(FRAMES)), "every frame went out"
    return arrived, gone, back, result["counters"]


def test_a_gone_detector_holds_the_next_frame_until_one_is_back():
    arrived, gone, back, counters = run(detector_wait_s=60.0, with_detector=True)
    assert back is not None, f"every frame went out before a detector was back: {sorted(arrived)}"
    during = [i for i, t in arrived.items() if gone < t < back]
    # only the frames already on their way (ingest runs its window, 2, ahead of the estimates)
    assert len(during) <= 2 and all(i > GONE_AT for i in during), during
    assert max(arrived) > GONE_AT + 3 and arrived[max(arrived)] > back  # the rest after it was back
    assert counters["errors"] == 0


@pytest.mark.parametrize("detector_wait_s,with_detector", [(0.0, True), (60.0, False)],
                         ids=["hold-off", "no-detector-ever"])
def test_without_the_hold_or_a_detector_the_frames_go_on(detector_wait_s, with_detector):
    """Negative controls: with the hold off, the frames go on while the detector is gone (here,
    all of the rest); a run whose detector never came up is paced by the estimates alone."""
    arrived, gone, back, counters = run(detector_wait_s, with_detector)
    if with_detector:  # the run may end before the new token comes
        during = [i for i, t in arrived.items() if gone < t < (back or float("inf"))]
        assert during == list(range(GONE_AT + 1, FRAMES)), during
    else:
        assert gone is None and arrived[FRAMES - 1] - arrived[0] < GAP_S
    assert counters["errors"] == 0
