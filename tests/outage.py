"""For the tests that kill a service mid-run: wait for the restarted instance itself, and say what
happened over the outage when a recovery assertion fails."""

from __future__ import annotations

import time
from pathlib import Path

from common.msgs import ScoreReply
from services.bus import alive_services, wait_for_alive
from services.launcher import router_config


def wait_restarted(pipe, service: str, timeout: float = 120.0) -> None:
    """Until the killed ``service``'s token has left the bus, then until the new instance's is on
    it. Right after a kill the bus can still list the dead instance under the same name: waiting
    for the name alone could let a test go on before the new instance is up. (A new instance up
    before the old token is seen to go shares its name: after 10 s the wait goes on to the name.)"""
    bus = router_config(pipe.hub_port, pipe.stream)
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline and service in alive_services(pipe.session, bus):
        time.sleep(0.02)
    assert wait_for_alive(pipe.session, bus, [service], timeout), f"no {service} on the bus after {timeout:.0f} s"


def held_after(at: int) -> dict:
    """A pipeline's ``ingest_options`` that stop its source before frame ``at + 1`` (the ingest
    breakpoint ``pause_before``) until it is resumed: a fault injected when the launcher hears of
    frame ``at`` then comes before any later frame goes out, however late a busy launcher hears."""
    return {"pause_before": at + 1}


class DetectorOutage:
    """``on_estimate`` for a run the launcher does not supervise: the detector is killed at the
    first estimate of frame ``at`` or later, the source let go and a new detector started at once.
    The pipeline's source stops before frame ``at + 1`` (``ingest_options``), so nothing later goes
    out before the kill however late a busy launcher hears of frame ``at``. Ingest (consumer
    pacing) then holds the source while no detector is on the bus, so the frames it sends before it
    sees the detector go are the only predictions. ``events``: ("killed" | "restarted", frame index)."""

    def __init__(self, at: int):
        self.at = at
        self.events: list[tuple[str, int]] = []
        self.ingest_options = held_after(at)
        """The pipeline's ``ingest_options``."""

    def __call__(self, pipe, est) -> None:
        if not self.events and est.frame_index >= self.at:
            pipe.kill("detector")
            self.events.append(("killed", est.frame_index))
            pipe.resume_source()
            pipe.start("detector")
            wait_restarted(pipe, "detector")
            self.events.append(("restarted", est.frame_index))

    def check(self, ests, report: str, most: int = 5) -> list[int]:
        """The recovery: the run's predictions all after the kill and at most ``most`` of them (the
        frames sent before ingest saw the detector go: none where it saw that before the first),
        and the last frame observed; the frames unobserved."""
        assert [e[0] for e in self.events] == ["killed", "restarted"], f"{self.events}\n{report}"
        unobserved = [e.frame_index for e in ests if not e.observed]
        assert all(i > self.events[0][1] for i in unobserved) and len(unobserved) <= most, report
        assert ests[-1].observed, report
        return unobserved


def outage_report(rec, log_dir: Path, estimates_key: str = "track/estimate", lines: int = 12) -> str:
    """What each frame got over the run (observed or not, the detector's non-OK replies by frame)
    and the last lines of the tracker's and detector's logs: the message of a failed recovery."""
    ests = sorted(rec.decoded(estimates_key), key=lambda e: e.frame_index)
    unobserved = [e.frame_index for e in ests if not e.observed]
    replies: dict[int, list[str]] = {}
    for r in rec.decoded("detector/reply"):
        if r.status != ScoreReply.OK:
            replies.setdefault(int(r.frame_index), []).append(ScoreReply.Status.Name(r.status))
    out = [f"estimates {len(ests)}, unobserved {unobserved}", f"non-OK replies by frame {replies}"]
    for service in ("tracker", "detector", "ingest"):
        p = Path(log_dir) / f"{service}.log"
        text = p.read_text(errors="replace").splitlines()[-lines:] if p.exists() else ["(no log)"]
        out.append(f"--- {service}.log (last {lines} lines)")
        out.extend(text)
    return "\n".join(out)
