"""Replaying a recording on the bus, and re-tracking its frames against a live detector.

``republish`` puts every recorded message back on its topic, paced by the recorded log times
(``speed`` x real time) or as fast as possible. ``retrack`` starts a detector and a tracker
service on a private loopback network, feeds them the recorded frames paced by the tracker's
estimates (nothing dropped), and compares every new estimate with the recorded one.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common.msgs import Estimate, FrameInfo, MultiEstimate
from common.recording import compare_estimates, read_recording
from services.bus import BusConfig, Inbox, ns_attachment, open_session, payload_bytes, wait_for_alive, publisher
from services.launcher import client_args, free_ports, router_config


def republish(path: str, bus: BusConfig, speed: float | None = 1.0) -> dict:
    """Publish every recorded message again; ``speed`` None = as fast as possible."""
    rec = read_recording(path)
    items = sorted(((t, topic, data) for topic, msgs in rec.messages.items() for t, data in msgs),
                   key=lambda x: x[0])
    sent = 0
    with open_session(bus) as session:
        pubs = {}
        t_first = items[0][0] if items else 0
        wall0 = time.monotonic()
        for t, topic, data in items:
            if speed:
                delay = wall0 + (t - t_first) / 1e9 / speed - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            pub = pubs.get(topic) or pubs.setdefault(topic, publisher(session, bus.key(topic)))
            pub.put(data, attachment=ns_attachment(t))
            sent += 1
    return {"messages": sent, "topics": len(rec.messages)}


def retrack(path: str, timeout: float = 600.0, log_dir: str | None = None) -> dict:
    rec = read_recording(path)
    run = rec.run
    images = rec.messages.get("frame/image", [])
    infos = [(t, d) for t, d in rec.messages.get("frame/info", [])]
    multi = run.get("multi_json") or None
    topic, cls = ("track/multi_estimate", MultiEstimate) if multi else ("track/estimate", Estimate)
    recorded = rec.decoded(topic)
    wanted = {e.frame_index for e in recorded}
    stream = f"retrack{int(time.time() * 1000) % 1000000}"
    hub = free_ports(1)[0]
    tmp = tempfile.TemporaryDirectory(prefix="polartrack-retrack-")
    logs = Path(log_dir or tmp.name)
    cfg = Path(tmp.name) / "tracker.json"
    init_box = json.loads(run["init_box"]) if run.get("init_box") else None
    cfg.write_text(json.dumps({"init_box": init_box or None, "settings": json.loads(run["settings_json"]),
                               "multi": multi}))
    procs = {}
    bus = router_config(hub, stream)
    session = open_session(bus)
    try:
        for name, extra in (("detector", []), ("tracker", ["--config", str(cfg)])):
            procs[name] = subprocess.Popen([sys.executable, "-m", f"services.{name}", "--stream", stream,
                                            *client_args(hub), *extra],
                                           stdout=open(logs / f"{name}.log", "ab"), stderr=subprocess.STDOUT)
        inbox = Inbox()
        new: dict[int, Estimate] = {}
        if session is not None:
            sub = session.declare_subscriber(bus.key(topic), inbox.callback("estimate"))
            if not wait_for_alive(session, bus, ["detector", "tracker"], 60.0):
                raise RuntimeError("detector/tracker did not start")
            pub_img = publisher(session, bus.key("frame/image"))
            pub_info = publisher(session, bus.key("frame/info"))
            image_by_time = {}
            for t, d in images:
                image_by_time.setdefault(t, []).append(d)
            deadline = time.monotonic() + timeout
            last_sent = -1
            for t, d in infos:
                info = FrameInfo.FromString(d)
                if info.end_of_stream:
                    break
                if info.index not in wanted:
                    continue  # the recorded (live) run skipped it: feed the same frames
                while last_sent >= 0 and last_sent not in new and time.monotonic() < deadline:
                    inbox.wait(0.1)
                    while (s := inbox.pop("estimate")) is not None:
                        e = cls.FromString(payload_bytes(s))
                        new[e.frame_index] = e
                for img in image_by_time.get(t, []):
                    pub_img.put(img, attachment=ns_attachment(t))
                pub_info.put(d, attachment=ns_attachment(t))
                last_sent = info.index
            while last_sent >= 0 and last_sent not in new and time.monotonic() < deadline:
                inbox.wait(0.1)
                while (s := inbox.pop("estimate")) is not None:
                    e = cls.FromString(payload_bytes(s))
                    new[e.frame_index] = e
            pub_info.put(FrameInfo(end_of_stream=True, index=last_sent + 1).SerializeToString())
            sub.undeclare()
        if multi:
            from common.multitarget_runner import compare_multi

            return compare_multi(recorded, [new[k] for k in sorted(new)])
        return compare_estimates(recorded, [new[k] for k in sorted(new)])
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.terminate()
                try:
                    p.wait(10)
                except subprocess.TimeoutExpired:
                    p.kill()
        session.close()
        tmp.cleanup()
