"""``replay`` republishing (rosbag2's play habits): the endpoint printed, ``--topics`` picks
topics, ``--start``/``--end`` a window in seconds from the first message, ``--loop`` repeats.
A recording with known log times is written by the recorder's sink; a subscriber of the test's
own (loopback, explicit endpoint, no scouting) counts what arrives per topic."""

from __future__ import annotations

import threading
import time

import pytest

from common.msgs import Estimate, FrameInfo
from services.bus import BusConfig, open_session, payload_bytes
from services.cli import main
from services.launcher import free_ports
from common.record.writer import McapSink
from services.replay import republish

T0 = 5 * 10**9
HZ = 10
N = 30  # 3 s of frame infos and estimates at 10 Hz, a status every second


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("republish") / "r.mcap"
    sink = McapSink(str(path), "lz4", 4 << 10)
    for i in range(N):
        ns = T0 + i * 10**9 // HZ
        sink.write("frame/info", FrameInfo(index=i, time_s=i / HZ, capture_ns=ns).SerializeToString(), ns, ns)
        sink.write("track/estimate", Estimate(frame_index=i, x=float(i)).SerializeToString(), ns, ns)
        if i % HZ == 0:
            sink.write("status/ingest", b"", ns, ns)
    sink.close()
    return str(path)


def counted(path, **kw):
    """republish(path, **kw) to a subscriber of the test's own: (report, {topic: [payloads]})."""
    port = free_ports(1)[0]
    bus = BusConfig(stream="rp", listen=[f"tcp/127.0.0.1:{port}"])
    got: dict[str, list[bytes]] = {}
    lock = threading.Lock()
    holder = {}

    def on_sample(s):
        with lock:
            got.setdefault(str(s.key_expr).removeprefix("polartrack/rp/"), []).append(payload_bytes(s))

    def ready():
        sub_bus = BusConfig(stream="rp", mode="client", connect=[f"tcp/127.0.0.1:{port}"])
        holder["session"] = open_session(sub_bus)
        holder["sub"] = holder["session"].declare_subscriber("polartrack/rp/**", on_sample)
        time.sleep(0.5)  # the subscription known to the publisher before the first message

    try:
        out = republish(path, bus, None, **kw, on_ready=ready)
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline and sum(map(len, got.values())) < out["messages"]:
            time.sleep(0.05)
    finally:
        if "session" in holder:
            holder["sub"].undeclare()
            holder["session"].close()
    return out, got


def test_every_message_once_per_pass_and_loops_repeat_it(recording):
    out, got = counted(recording, loops=3)
    assert out["passes"] == 3 and out["messages"] == 3 * (2 * N + 3)
    assert {k: len(v) for k, v in got.items()} == {"frame/info": 3 * N, "track/estimate": 3 * N, "status/ingest": 9}
    indices = [FrameInfo.FromString(b).index for b in got["frame/info"]]
    assert indices == list(range(N)) * 3  # each pass in the recorded order


def test_topics_pick_and_a_missing_topic_is_reported(recording):
    out, got = counted(recording, topics=["track/estimate", "no/such"])
    assert set(got) == {"track/estimate"} and len(got["track/estimate"]) == N
    assert out["topics_not_found"] == ["no/such"]


def test_start_and_end_are_seconds_from_the_first_message(recording):
    out, got = counted(recording, start_s=1.0, end_s=2.0, topics=["frame/info"])
    indices = [FrameInfo.FromString(b).index for b in got["frame/info"]]
    assert indices == list(range(10, 21))  # 1.0 s .. 2.0 s inclusive at 10 Hz
    out, got = counted(recording, start_s=2.55)
    assert [Estimate.FromString(b).frame_index for b in got["track/estimate"]] == list(range(26, N))
    assert "status/ingest" not in got  # the last status is at 2.0 s


def test_cli_prints_the_endpoint_and_refuses_bad_windows(recording, capsys):
    assert main(["replay", recording, "--max", "--topics", "status/ingest"]) == 0
    out = capsys.readouterr().out
    first, last = out.splitlines()[0], out.splitlines()[-1]
    assert first.startswith(f"replaying {recording} on polartrack/replay/** (listening on tcp/127.0.0.1:")
    assert "--connect tcp/127.0.0.1:" in first and last == "republished 3 messages on 1 topics"
    for bad, says in ((["--start", "2", "--end", "1"], "need 0 <= start < end"),
                      (["--start", "-1"], "must be at least 0"),
                      (["--loop", "-2"], "--loop N"),
                      (["--offline", "--topics", "frame/info"], "apply to republishing")):
        assert main(["replay", recording, *bad]) == 2
        err = capsys.readouterr().err
        assert says in err and err.count("\n") == 1 and "Traceback" not in err
