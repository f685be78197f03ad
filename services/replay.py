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
from common.validation import FrameOrder, Invalid, check_frame_info, decode
from common.record.reader import ReadReport, RecordingError, read_recording, stream_messages, warn_read
from common.record.retrack import compare_estimates
from services.bus import BusConfig, Inbox, ns_attachment, open_session, payload_bytes, wait_for_alive, publisher
from services.launcher import client_args, free_ports, router_config, stop_process


def republish(path: str, bus: BusConfig, speed: float | None = 1.0, warn=None, *, topics=None,
              start_s: float = 0.0, end_s: float | None = None, loops: int = 1, on_ready=None) -> dict:
    """Publish the recorded messages again, streamed from the file in its order (one chunk in
    memory at a time), paced by the log times; ``speed`` None = as fast as possible. Only
    ``topics`` (all when None); only the messages logged from ``start_s`` to ``end_s`` seconds
    after the recording's first message; ``loops`` passes over it (0: until interrupted), each
    paced from its own start. ``on_ready()`` is called once the session is open (before the
    first message). A file cut short is published up to the cut; untrustworthy records are
    skipped and counted."""
    from common.record.info import InfoError, recording_info

    if start_s < 0 or (end_s is not None and end_s <= start_s):
        raise RecordingError(f"--start {start_s} / --end {end_s}: need 0 <= start < end")
    try:
        t0 = recording_info(path).start_ns  # the recording's first log time (its summary)
    except InfoError:
        t0 = None  # unreadable: the stream below says why (or the first message read sets it)
    wanted = None if topics is None else set(topics)
    report = ReadReport()
    sent, passes = 0, 0
    per_topic: dict[str, int] = {}
    with open_session(bus) as session:
        if on_ready is not None:
            on_ready()
        pubs = {}
        while loops == 0 or passes < loops:
            report = ReadReport()  # counted afresh each pass: the last pass's figures are reported
            wall0 = time.monotonic()
            for topic, t, data in stream_messages(path, wanted, report):
                t0 = t if t0 is None else t0
                lo = t0 + int(start_s * 1e9)
                if t < lo or (end_s is not None and t > t0 + int(end_s * 1e9)):
                    continue
                if speed:
                    delay = wall0 + (t - lo) / 1e9 / speed - time.monotonic()
                    if delay > 0:
                        time.sleep(min(delay, 60.0))  # a garbled log time never stalls the replay for long
                pub = pubs.get(topic) or pubs.setdefault(topic, publisher(session, bus.key(topic)))
                pub.put(data, attachment=ns_attachment(t))
                per_topic[topic] = per_topic.get(topic, 0) + 1
                sent += 1
            passes += 1
            if sent == 0:
                break  # nothing in the window: looping would only spin
    warn_read(path, report, warn)
    if sent == 0 and (report.cut or report.skipped):
        raise RecordingError(f"{path}: not a readable MCAP file (no message could be read: "
                             f"{report.cut or report.skipped})")
    missing = sorted(wanted - set(per_topic)) if wanted is not None else []
    return {"messages": sent, "topics": len(per_topic), "per_topic": per_topic, "passes": passes,
            **({"topics_not_found": missing} if missing else {}), **_read_stats(report)}


def _read_stats(report: ReadReport) -> dict:
    out = {}
    if report.cut:
        out["cut"] = report.cut
    if report.skipped:
        out["records_skipped"] = dict(report.skipped)
    if report.malformed:
        out["malformed"] = dict(report.malformed)
    return out


def retrack(path: str, timeout: float = 600.0, log_dir: str | None = None) -> dict:
    rec = read_recording(path, skip=("frame/image",))  # the frames are streamed below
    run = rec.run
    multi = run.get("multi_json") or None
    topic, cls = ("track/multi_estimate", MultiEstimate) if multi else ("track/estimate", Estimate)
    recorded = rec.decoded(topic)
    wanted = {e.frame_index for e in recorded}
    if not multi:
        from common.record.retrack import run_settings

        run_settings(rec)  # garbled settings or box: one line here, not a tracker dying later
    try:
        settings_json = json.loads(run.get("settings_json") or "")
        init_box = json.loads(run["init_box"]) if run.get("init_box") else None
        if not isinstance(settings_json, dict):
            raise ValueError("not a JSON object")
    except (ValueError, TypeError) as exc:
        raise RecordingError(f"{path}: the run metadata's settings or init box are not valid JSON "
                             f"({type(exc).__name__}: {str(exc)[:100]})") from None
    stream = f"retrack{int(time.time() * 1000) % 1000000}"
    hub = free_ports(1)[0]
    tmp = tempfile.TemporaryDirectory(prefix="polartrack-retrack-")
    logs = Path(log_dir or tmp.name)
    cfg = Path(tmp.name) / "tracker.json"
    cfg.write_text(json.dumps({"init_box": init_box or None, "settings": settings_json,
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
            deadline = time.monotonic() + timeout
            last_sent = -1
            order = FrameOrder()
            held: dict[int, list[bytes]] = {}  # log time -> frame images not yet sent (bounded)

            def collect() -> None:
                while (s := inbox.pop("estimate")) is not None:
                    try:
                        e = cls.FromString(payload_bytes(s))
                    except Exception:  # noqa: BLE001 - nothing on the bus stops the comparison
                        continue
                    new[e.frame_index] = e

            def send(t: int, d: bytes, images: list[bytes]) -> None:
                nonlocal last_sent
                try:
                    info = decode(FrameInfo, d, "frame/info")
                    check_frame_info(info, order)
                except Invalid:
                    rec.report.bad("frame/info")
                    return
                if info.end_of_stream or info.index not in wanted:
                    return  # the recorded (live) run skipped it: feed the same frames
                while last_sent >= 0 and last_sent not in new and time.monotonic() < deadline:
                    inbox.wait(0.1)
                    collect()
                for img in images:
                    pub_img.put(img, attachment=ns_attachment(t))
                pub_info.put(d, attachment=ns_attachment(t))
                last_sent = info.index

            # streamed in file order: a frame's image and info share its log time; an info is sent
            # with the images of its time read before it, or (one group later) just after it
            group_t, group_infos = None, []
            for rtopic, t, d in rec.stream(["frame/image", "frame/info"]):
                if t != group_t:
                    for gt, gd in group_infos:
                        send(gt, gd, held.pop(gt, []))
                    group_t, group_infos = t, []
                    while len(held) > 8:
                        held.pop(next(iter(held)))
                if rtopic == "frame/image":
                    held.setdefault(t, []).append(d)
                else:
                    group_infos.append((t, d))
            for gt, gd in group_infos:
                send(gt, gd, held.pop(gt, []))
            while last_sent >= 0 and last_sent not in new and time.monotonic() < deadline:
                inbox.wait(0.1)
                collect()
            pub_info.put(FrameInfo(end_of_stream=True, index=last_sent + 1).SerializeToString())
            sub.undeclare()
        if multi:
            from common.record.retrack import compare_multi

            out = compare_multi(recorded, [new[k] for k in sorted(new)])
        else:
            out = compare_estimates(recorded, [new[k] for k in sorted(new)])
        if rec.report.malformed:
            out["malformed"] = dict(rec.report.malformed)
        return out
    finally:
        for p in procs.values():
            stop_process(p)
        session.close()
        tmp.cleanup()
