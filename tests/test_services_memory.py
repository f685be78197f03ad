"""Bounded memory on long runs (issue 17: the viewer grew 55 MB and ingest 31 MB in an 8-minute
soak): the viewer's Rerun stream is flushed as it goes, ingest keeps no estimates it never
reads, and the soak benchmark's RSS summary says when a service grows beyond the bound."""

from __future__ import annotations

import signal
import threading
import time
from unittest import mock

import numpy as np
import pytest

from common.msgs import Estimate, FrameInfo
from services.bus import BusConfig, Inbox, Stopper, open_session
from services.commands.bench import RSS_BOUND_MB, RssSampler
from services.launcher import free_ports
from common.record.rerun import FLUSH_EVERY, RunLogger

pytestmark = pytest.mark.slow  # services as separate processes on a loopback bus


def test_run_logger_flushes_rerun_every_256_messages_without_waiting():
    """Rerun's batcher held what was logged until flushed (14 MB per 1,000 frames): the logger
    starts a flush every FLUSH_EVERY messages, never waiting for it."""
    rec = mock.MagicMock()
    logger = RunLogger(rec)
    for i in range(1000):
        logger.log_message("frame/info", FrameInfo(index=i, time_s=i / 30, capture_ns=i).SerializeToString(), i)
    assert FLUSH_EVERY == 256 and logger.stats["infos"] == 1000
    assert rec.flush.call_args_list == [mock.call(timeout_sec=0)] * 3  # at 256, 512, 768


def fake_sampler(series: dict[str, list[float]], every: float = 5.0) -> RssSampler:
    s = RssSampler(pipe=None, every=every)
    s.samples = {k: [(i * every, v) for i, v in enumerate(vals)] for k, vals in series.items()}
    return s


def test_rss_summary_bounds_growth_after_the_start_up():
    n = 361  # 30 minutes at one sample every 5 s
    start_up = np.r_[np.linspace(150, 400, 20), np.full(n - 20, 400.0)]  # imports, first frames: then flat
    leak = np.r_[np.linspace(150, 400, 20), 400 + np.arange(n - 20) * (5 / 12)]  # +5 MB a minute (12 samples)
    noisy = start_up + np.random.default_rng(0).uniform(-3, 3, n)
    out = fake_sampler({"flat": list(start_up), "leak": list(leak), "noisy": list(noisy)}).summary()
    assert out["flat"]["within_bound"] and out["flat"]["growth_mb"] == 0.0 and out["flat"]["slope_mb_per_h"] == 0.0
    assert out["flat"]["start_mb"] == 150.0 and out["flat"]["max_mb"] == out["flat"]["end_mb"] == 400.0
    assert out["noisy"]["within_bound"] and abs(out["noisy"]["slope_mb_per_h"]) < 5
    assert not out["leak"]["within_bound"] and out["leak"]["growth_mb"] > RSS_BOUND_MB
    assert abs(out["leak"]["slope_mb_per_h"] - 300.0) < 1.0  # 5 MB a minute


def test_rss_sampler_samples_live_processes():
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-c", "import time; b = bytearray(64 << 20); time.sleep(30)"])
    try:
        pipe = mock.Mock(procs={"hog": proc})
        with RssSampler(pipe, every=0.2) as s:
            time.sleep(1.5)
        out = s.summary()
    finally:
        proc.kill()
        proc.wait(10)
    assert out["hog"]["max_mb"] > 64 and out["launcher"]["samples"] >= 3


def test_ingest_keeps_no_estimates_it_does_not_read(monkeypatch):
    """Real-time and max pacing read no estimate after the first frame: ingest stops listening, so
    a stream of estimates (here a flood, 4,096 of which the old ingest kept) holds nothing."""
    import services.ingest as ingest

    port = free_ports(1)[0]
    boxes_seen: list[int] = []
    flood_sent_at_frame: list[int] = []
    sent = [0]
    inboxes: list[Inbox] = []

    class Watched(Inbox):
        def __init__(self):
            super().__init__()
            inboxes.append(self)

    import services.bus as bus_module

    real_publisher = bus_module.publisher  # what ServiceShell.publisher calls

    def watched_publisher(session, key, **kwargs):
        pub = real_publisher(session, key, **kwargs)
        if key.endswith("/frame/info"):
            put = pub.put

            def put_and_look(data, **kw):
                info = FrameInfo.FromString(data)
                if not info.end_of_stream and info.index >= 3:
                    time.sleep(0.05)  # the flood goes on meanwhile
                    boxes_seen.append(sum(len(b) for b in inboxes[0].boxes.values()))
                    flood_sent_at_frame.append(sent[0])
                put(data, **kw)

            pub.put = put_and_look
        return pub

    monkeypatch.setattr(ingest, "Inbox", Watched)
    monkeypatch.setattr(bus_module, "publisher", watched_publisher)
    bus = BusConfig(stream="mem", listen=[f"tcp/127.0.0.1:{port}"])
    cfg = ingest.IngestSettings(source="synthetic:0", frames=24, pace="max")
    stop = threading.Event()

    def flood():
        with open_session(BusConfig(stream="mem", connect=[f"tcp/127.0.0.1:{port}"])) as s:
            pub = s.declare_publisher("polartrack/mem/track/estimate")
            data = Estimate(frame_index=0, x=1.0, y=2.0).SerializeToString()
            while not stop.is_set():
                pub.put(data)
                sent[0] += 1
                time.sleep(0.0005)

    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    t = threading.Thread(target=flood, daemon=True)
    t.start()
    try:
        counters = ingest.serve(bus, cfg, Stopper())
    finally:
        stop.set()
        t.join(10)
        for sig, h in handlers.items():
            signal.signal(sig, h)
    assert counters["published"] == 24
    assert len(boxes_seen) == 21 and boxes_seen == [0] * 21, boxes_seen
    assert flood_sent_at_frame[-1] - flood_sent_at_frame[0] > 100  # estimates kept coming meanwhile


def test_a_closed_inbox_box_keeps_nothing_delivered_after_it_was_closed():
    """Zenoh may still deliver a sample that was on its threads when the subscription was undeclared
    (ingest kept four of a flood that way under load): a closed box drops it, and the other boxes
    keep theirs. Negative control: the same put before the close is kept."""
    inbox = Inbox()
    put_estimate = inbox.callback("estimate", maxlen=8)
    put_multi = inbox.callback("multi", maxlen=8)
    put_estimate(b"kept")
    assert inbox.pending("estimate") == 1
    inbox.close("estimate")
    assert inbox.pending("estimate") == 0
    late = threading.Thread(target=lambda: [put_estimate(b"late") for _ in range(20)])
    late.start()
    late.join(10)
    put_multi(b"other")
    assert inbox.pending("estimate") == 0 and inbox.dropped["estimate"] == 0
    assert inbox.pending("multi") == 1 and inbox.pop("multi") == b"other"
