"""The pipeline's graph, declared once: every key on the bus, its message type, who publishes
it, who listens, and whether the recorder keeps it.

Keys are suffixes of ``polartrack/<stream>/``. ``<service>`` stands for each service of the run
(``status/<service>`` is ``status/ingest``, ``status/detector``, ...). The services, the
recorder (what it records: :data:`common.msgs.TOPICS`), the validation (who may speak on a key:
:data:`common.validation.SPEAKERS`), replay and the viewer read it from here;
``polartrack graph`` prints it, and ``tests/test_topics.py`` checks every key the services
use against it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

from common.msgs.polartrack.messages_pb2 import (Estimate, FrameInfo, MultiEstimate, ParticleCloud, RunConfig, ScoreQuery,
                                                 ScoreReply, ServiceStatus, Template)

SERVICES = ("ingest", "detector", "tracker", "recorder", "viewer", "router")
"""The processes of a run that speak on the bus (the launcher and replay listen, or stand in for
ingest)."""

Kind = Literal["publish", "query", "liveliness"]


@dataclass(frozen=True)
class Topic:
    key: str
    """Suffix after ``polartrack/<stream>/``; ``<service>``: one key per service."""
    message: type | None
    """Its protobuf message (None: JSON or a liveliness token)."""
    publishers: tuple[str, ...]
    """Who puts on it (a query: who answers it)."""
    subscribers: tuple[str, ...]
    """Who listens (a query: who asks)."""
    recorded: bool
    kind: Kind
    what: str

    def keys(self, services=SERVICES) -> list[str]:
        """The concrete keys: one per service for a ``<service>`` key."""
        if "<service>" not in self.key:
            return [self.key]
        return [self.key.replace("<service>", s) for s in services]


GRAPH: tuple[Topic, ...] = (
    Topic("run/config", RunConfig, ("ingest",), ("recorder", "viewer"), True, "publish",
          "the run's source, first box, settings and seed, once before the first frame (the MCAP's run metadata)"),
    Topic("frame/image", RawImage, ("ingest",), ("detector", "tracker", "recorder", "viewer"), True, "publish",
          "the frame's pixels: foxglove.RawImage, or CompressedImage (common.msgs.image_wire); frame_id 'camera'"),
    Topic("frame/info", FrameInfo, ("ingest",), ("tracker", "recorder", "viewer", "launcher"), True, "publish",
          "the frame's index, capture time, size, homography and ground truth"),
    Topic("detector/score", ScoreQuery, ("detector",), ("tracker",), False, "query",
          "the tracker's batched question about a frame (ScoreQuery), answered with a ScoreReply"),
    Topic("detector/query", ScoreQuery, ("detector",), ("recorder",), True, "publish",
          "each query the detector answered, as it answered it (replay --offline matches them)"),
    Topic("detector/reply", ScoreReply, ("detector",), ("recorder",), True, "publish",
          "each reply the detector sent"),
    Topic("template", Template, ("tracker", "detector"), ("detector", "recorder", "viewer"), True, "publish",
          "the target's P-matrix: the first from the detector, the adapted ones from the tracker"),
    Topic("track/estimate", Estimate, ("tracker",), ("ingest", "recorder", "viewer", "launcher"), True, "publish",
          "one target's estimate a frame: the oriented box, p(visible), velocity (ingest paces on it)"),
    Topic("track/particles", ParticleCloud, ("tracker",), ("recorder", "viewer"), True, "publish",
          "the particle cloud after each step, for display"),
    Topic("track/multi_estimate", MultiEstimate, ("tracker",), ("ingest", "recorder", "viewer", "launcher"), True,
          "publish", "several articulated targets' parts a frame"),
    Topic("track/annotations", ImageAnnotations, ("recorder",), (), True, "publish",
          "the track drawn for Foxglove (foxglove.ImageAnnotations), made by the recorder from the estimates"),
    Topic("status/<service>", ServiceStatus, SERVICES, ("recorder", "viewer", "launcher"), True, "publish",
          "each service's counters, once a second and at exit"),
    Topic("health/<service>", None, SERVICES[:-1], ("launcher",), False, "publish",
          "the messages a service refused, by key and reason (JSON), when they change"),
    Topic("alive/<service>", None, SERVICES[:-1], ("ingest", "launcher"), False, "liveliness",
          "a liveliness token while the service runs (ingest waits for them)"),
)


def topic_suffix(key: str, stream: str | None = None) -> str:
    """A full key or an MCAP channel's topic -> its suffix: ``polartrack/<stream>/frame/info`` ->
    ``frame/info`` (with ``stream``: only that stream's prefix is taken off); a suffix stays."""
    t = key.lstrip("/")
    if stream is not None:
        prefix = f"polartrack/{stream}/"
        return t[len(prefix):] if t.startswith(prefix) else key
    if t.startswith("polartrack/"):
        parts = t.split("/", 2)
        return parts[2] if len(parts) == 3 else t
    return t


def topic(key: str) -> Topic | None:
    """The declared topic of a concrete key (``status/tracker`` -> ``status/<service>``)."""
    for t in GRAPH:
        if t.key == key or ("<service>" in t.key and key.startswith(t.key.split("<service>")[0])
                            and "/" not in key[len(t.key.split("<service>")[0]):]):
            return t
    return None


def recorded_messages() -> dict[str, type]:
    """Recorded key -> message class (the fixed keys; ``status/<service>`` is matched apart)."""
    return {t.key: t.message for t in GRAPH if t.recorded and t.message is not None and "<service>" not in t.key}


def speakers() -> dict[str, tuple[str, ...]]:
    """Fixed key -> the services that may publish on it; for a query, ``KEY`` -> who answers and
    ``KEY/query`` -> who asks."""
    out: dict[str, tuple[str, ...]] = {}
    for t in GRAPH:
        if "<service>" in t.key:
            continue
        out[t.key] = t.publishers
        if t.kind == "query":
            out[f"{t.key}/query"] = t.subscribers
    return out


def table() -> str:
    """The graph as a Markdown table (``polartrack graph``; the README's)."""
    rows = ["| key | message | published by | heard by | recorded | what |", "|---|---|---|---|---|---|"]
    for t in GRAPH:
        name = t.message.DESCRIPTOR.full_name if t.message is not None else ("token" if t.kind == "liveliness" else "JSON")
        if t.kind == "query":
            name = f"{name} -> {ScoreReply.DESCRIPTOR.full_name}"
        pubs = {SERVICES: "each service", SERVICES[:-1]: "each service but the router"}.get(
            t.publishers, ", ".join(t.publishers))
        verb = " (answers)" if t.kind == "query" else ""
        rows.append(f"| `{t.key}` | {name} | {pubs}{verb} | {', '.join(t.subscribers) or '(Foxglove)'}"
                    f"{' (asks)' if t.kind == 'query' else ''} | {'yes' if t.recorded else 'no'} | {t.what} |")
    return "\n".join(rows)


def mermaid() -> str:
    """The graph as a Mermaid flowchart: service -> key -> service (liveliness, status and health
    left out: every service has them)."""
    lines = ["flowchart LR"]
    for t in GRAPH:
        if "<service>" in t.key:
            continue
        node = t.key.replace("/", "_")
        shape = f'{node}{{{{"{t.key}"}}}}' if t.kind == "query" else f'{node}(["{t.key}"])'
        lines.append(f"  {shape}")
        for p in t.publishers:
            lines.append(f"  {p} --> {node}" if t.kind != "query" else f"  {node} -.->|asks| {p}")
        for s in t.subscribers:
            lines.append(f"  {node} --> {s}" if t.kind != "query" else f"  {s} -.->|query| {node}")
        if t.recorded and "recorder" not in t.subscribers and "recorder" not in t.publishers:
            lines.append(f"  {node} --> recorder")
    return "\n".join(lines)
