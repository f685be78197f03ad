"""Zenoh plumbing shared by the services: explicit session config, topic keys, the capture-time
attachment, liveliness, service counters and clean shutdown.

Every session is opened from an explicit :class:`BusConfig`: peer mode on loopback by default,
multicast scouting off; endpoints and mode (peer, or client of a router) are configurable for
multi-host use.
"""

from __future__ import annotations

import json
import logging
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Literal

import zenoh
from pydantic import BaseModel, ConfigDict, Field

from common.msgs.topics import topic_suffix
from common.validation import Counters  # noqa: F401 (the services' counters: re-exported for them)

log = logging.getLogger("polartrack.bus")


class TlsConfig(BaseModel):
    """Zenoh's TLS transport (endpoints ``tls/HOST:PORT``), mutual by default: certificates from
    ``tools/gen_certs.sh OUT_DIR [HOST ...] --client NAME ...``."""

    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)

    root_ca_certificate: str
    """PEM of the CA that signed every certificate of the deployment"""
    certificate: str | None = None
    """this process's certificate (PEM): the router's, or a client's (mTLS; its common name is what
    access-control rules match)"""
    private_key: str | None = None
    """the certificate's private key (PEM)"""
    mtls: bool = True
    """mutual TLS: a client without a certificate signed by the CA cannot connect"""


class BusConfig(BaseModel):
    """How a service joins the bus."""

    model_config = ConfigDict(frozen=True, extra="forbid", use_attribute_docstrings=True)

    stream: str = Field("default", pattern=r"^[A-Za-z0-9_\-]+$")
    """Namespace of this pipeline: keys are polartrack/<stream>/..."""
    mode: Literal["peer", "client", "router"] = "peer"
    """peer, client of a Zenoh router, or router (the launcher hosts one on loopback)"""
    listen: list[str] = Field(default_factory=list)
    """Zenoh endpoints to listen on, e.g. tcp/127.0.0.1:7447"""
    connect: list[str] = Field(default_factory=list)
    """Zenoh endpoints to connect to"""
    multicast_scouting: bool = False
    """Zenoh multicast scouting (off: explicit endpoints only)"""
    shared_memory: bool = False
    """Zenoh shared memory for the large messages (the frame images). Off by default: zenoh 1.10 leaves
    its segment files in /dev/shm when a process exits, for the next one to clean; the launcher turns it
    on for the processes it starts and removes their segments (services/shm_files.py)"""
    shm_pool_mb: int = Field(96, ge=8, le=4096)
    """Shared memory: the pool a publisher allocates its messages in (MiB). Receivers release a
    message's buffer once decoded; when the pool is full, Zenoh falls back to copies"""
    shm_threshold_kb: int = Field(1024, ge=4)
    """Shared memory: messages at least this large (KiB) go through it; smaller ones (queries, replies,
    estimates) through the socket, which is quicker for them (with every message through shared memory,
    bench --pipeline made 3.7 fps; with the frames only, 11)"""
    tls: TlsConfig | None = None
    """TLS (mTLS) transport for multi-host deployments"""
    access_control: dict | None = None
    """Zenoh's access_control section as is (a router's rules: which subjects, e.g. cert_common_names,
    may put or declare on which keys)"""
    ids: dict[str, str] = Field(default_factory=dict)
    """The run's per-service sender ids ({service: id}, given by the launcher): every message carries
    its sender's id, and a service accepts a key only from the run's services that speak on it
    (common.validation.SPEAKERS). Empty: every sender accepted"""

    def zenoh_config(self) -> zenoh.Config:
        c = zenoh.Config()
        c.insert_json5("mode", json.dumps(self.mode))
        c.insert_json5("scouting/multicast/enabled", json.dumps(self.multicast_scouting))
        c.insert_json5("transport/shared_memory/enabled", json.dumps(self.shared_memory))
        if self.shared_memory:
            c.insert_json5("transport/shared_memory/transport_optimization", json.dumps({
                "enabled": True, "pool_size": self.shm_pool_mb << 20,
                "message_size_threshold": self.shm_threshold_kb << 10}))
        if self.tls is not None:
            t = self.tls
            tls = {"root_ca_certificate": t.root_ca_certificate, "enable_mtls": t.mtls}
            if t.certificate and t.private_key:
                tls |= {"listen_certificate": t.certificate, "listen_private_key": t.private_key,
                        "connect_certificate": t.certificate, "connect_private_key": t.private_key}
            c.insert_json5("transport/link/tls", json.dumps(tls))
        if self.access_control is not None:
            c.insert_json5("access_control", json.dumps(self.access_control))
        c.insert_json5("listen/endpoints", json.dumps(list(self.listen)))
        c.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
        # peers start in any order: retry connections quickly so the mesh forms in well under a second
        c.insert_json5("connect/retry", json.dumps({"period_init_ms": 50, "period_max_ms": 500,
                                                    "period_increase_factor": 1.5}))
        return c

    def key(self, suffix: str) -> str:
        return f"polartrack/{self.stream}/{suffix}"

    def suffix(self, key: str) -> str:
        return topic_suffix(key, self.stream)


class BusUnavailable(SystemExit):
    """The Zenoh session could not be opened (no router at the endpoints, a bad certificate): the
    process ends with this one-line message (exit status 1), not a traceback."""


def open_session(bus: BusConfig) -> zenoh.Session:
    try:
        return zenoh.open(bus.zenoh_config())
    except zenoh.ZError as exc:
        reason = str(exc).split("  at ")[0].strip()  # drop the Rust source location
        where = ", ".join(bus.connect) or ", ".join(bus.listen) or "the default endpoints"
        hint = " (is the router running? `polartrack run` starts one)" if bus.connect else ""
        raise BusUnavailable(f"{Path(sys.argv[0]).stem or 'polartrack'}: error: cannot join the Zenoh bus at "
                             f"{where}: {reason}{hint}") from None


_IDENTITY = b""
"""This process's sender id (set once by :func:`set_identity`), appended to every attachment."""


def set_identity(sender: str) -> None:
    """This process speaks as ``sender`` (its per-run id; "" for none) from now on."""
    global _IDENTITY
    _IDENTITY = sender.encode()[:64]


class Publisher:
    """A Zenoh publisher whose every message carries this process's sender id (an attachment
    of the current time when the caller gives none)."""

    def __init__(self, pub):
        self._pub = pub

    def put(self, data, attachment: bytes | None = None, **kwargs) -> None:
        if attachment is None and _IDENTITY:
            attachment = ns_attachment(time.time_ns())
        if attachment is None:
            self._pub.put(data, **kwargs)
        else:
            self._pub.put(data, attachment=attachment, **kwargs)

    def __getattr__(self, name):
        return getattr(self._pub, name)


def publisher(session: zenoh.Session, key: str, remote_only: bool = False) -> Publisher:
    """A reliable publisher that blocks rather than drops when the link is congested: every
    message must reach the recorder (Zenoh's default for puts is to drop under congestion,
    which lost whole 2.7 MB frames). ``remote_only``: not delivered to this session's own
    subscribers."""
    extra = {"allowed_destination": zenoh.Locality.REMOTE} if remote_only else {}
    return Publisher(session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK,
                                               reliability=zenoh.Reliability.RELIABLE, **extra))


def query_options() -> dict:
    """A query goes to every queryable on the key and every reply comes back as it is (no
    consolidation): the run's detector always gets it, whoever else answers, and the querier
    picks the reply of the run's detector by its sender id (with Zenoh's defaults, a second
    queryable could be the only one asked, or its reply the one kept)."""
    return {"target": zenoh.QueryTarget.ALL, "consolidation": zenoh.ConsolidationMode.NONE}


def ns_attachment(capture_ns: int) -> bytes:
    """The frame's capture time travels with every message about it (the MCAP log time),
    followed by the sender's id (nothing when this process has none)."""
    return int(capture_ns).to_bytes(8, "little", signed=True) + _IDENTITY


def _attachment_bytes(obj) -> bytes:
    att = getattr(obj, "attachment", None)
    return b"" if att is None else att.to_bytes()


def attachment_ns(sample) -> int | None:
    b = _attachment_bytes(sample)
    return int.from_bytes(b[:8], "little", signed=True) if 8 <= len(b) <= 8 + 64 else None


def attachment_sender(sample) -> str:
    """The sender id a sample, query or reply carries ("" when none)."""
    b = _attachment_bytes(sample)
    if not 8 < len(b) <= 8 + 64:
        return ""
    return b[8:].decode(errors="replace")


def make_guard(bus: BusConfig, service: str, counters: "Counters | None", logger: logging.Logger):
    """A service's :class:`common.validation.Guard`: the run's senders, each rejected message
    also counted in the service's ``malformed``."""
    from common.validation import Guard, Senders

    return Guard(service, Senders(bus.ids), logger,
                 on_reject=(lambda key, reason: counters.add("malformed")) if counters is not None else None)


def payload_bytes(obj) -> bytes:
    p = getattr(obj, "payload", None)
    return b"" if p is None else p.to_bytes()


class StatusTicker:
    """Publishes a service's :class:`Counters` as a ServiceStatus on ``pub`` at most once a
    ``period``, and with a ``guard``, its dropped messages per key and reason as JSON on
    ``health/<service>`` (on ``health_pub``) whenever they changed."""

    def __init__(self, pub, counters: Counters, period: float = 1.0, guard=None, health_pub=None):
        self.pub, self.counters, self.period = pub, counters, period
        self.guard, self.health_pub = guard, health_pub
        self.last = time.monotonic()
        self._health_sent = None

    def _health(self, **put_kwargs) -> None:
        if self.guard is None or self.health_pub is None:
            return
        data = self.guard.rejects.to_json()
        if data != self._health_sent:
            self.health_pub.put(data, **put_kwargs)
            self._health_sent = data

    def tick(self, **put_kwargs) -> bool:
        """Publish if a period has passed since the last time (True then)."""
        now = time.monotonic()
        if now - self.last <= self.period:
            return False
        self.pub.put(self.counters.status().SerializeToString(), **put_kwargs)
        self._health(**put_kwargs)
        self.last = now
        return True

    def final(self, **put_kwargs) -> None:
        """The last status (``final``) and health."""
        self._health_sent = None
        self._health(**put_kwargs)
        self.pub.put(self.counters.status(final=True).SerializeToString(), **put_kwargs)
        time.sleep(0.05)  # on their way before the session closes


class ServiceShell:
    """What every service does around its own work, in one place: its counters and its guard
    (:func:`make_guard`), the Zenoh session, the subscriptions and queryables it declares, and,
    once it is ready, its status and health publishers and its liveliness token (:meth:`alive`:
    ingest and the launcher wait for the token). Leaving the ``with`` block undeclares the token
    and everything declared, newest first, and closes the session, whatever happened inside.

    ``open()`` joins the bus before the ``with`` block (the viewer: a bus that cannot be joined
    leaves no empty file behind)."""

    def __init__(self, bus: BusConfig, service: str, logger: logging.Logger, counters: "Counters | None" = None):
        self.bus, self.service = bus, service
        self.counters = counters if counters is not None else Counters(service)
        self.guard = make_guard(bus, service, self.counters, logger)
        self.session = None
        self.status: StatusTicker | None = None
        self._declared: list = []
        self._token = None

    def open(self) -> "ServiceShell":
        if self.session is None:
            self.session = open_session(self.bus)
        return self

    def __enter__(self) -> "ServiceShell":
        return self.open()

    def subscribe(self, key: str, handler, **kwargs):
        sub = self.session.declare_subscriber(self.bus.key(key), handler, **kwargs)
        self._declared.append(sub)
        return sub

    def queryable(self, key: str, handler, **kwargs):
        q = self.session.declare_queryable(self.bus.key(key), handler, **kwargs)
        self._declared.append(q)
        return q

    def publisher(self, key: str, **kwargs) -> "Publisher":
        return publisher(self.session, self.bus.key(key), **kwargs)

    def alive(self) -> StatusTicker:
        """The service is ready: its status and health publishers, its liveliness token, and the
        ticker that publishes its counters (``tick`` in the loop, ``final`` at the end)."""
        pub_status = self.publisher(f"status/{self.service}")
        pub_health = self.publisher(f"health/{self.service}")
        self._token = self.session.liveliness().declare_token(self.bus.key(f"alive/{self.service}"))
        self.status = StatusTicker(pub_status, self.counters, guard=self.guard, health_pub=pub_health)
        return self.status

    def undeclare(self, declared) -> None:
        """Undeclare one subscription now (ingest stops listening once it paces by the clock)."""
        if declared in self._declared:
            self._declared.remove(declared)
            declared.undeclare()

    def __exit__(self, *exc) -> None:
        try:
            if self._token is not None:
                self._token.undeclare()
                self._token = None
            while self._declared:
                self._declared.pop().undeclare()
        finally:
            session, self.session = self.session, None
            if session is not None:
                session.close()


class Stopper:
    """Set on SIGINT/SIGTERM/SIGHUP; services poll it between messages."""

    def __init__(self):
        self.event = threading.Event()
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            try:
                signal.signal(sig, self._handle)
            except ValueError:  # not the main thread (tests)
                pass

    def _handle(self, signum, frame) -> None:
        self.event.set()

    @property
    def stopped(self) -> bool:
        return self.event.is_set()

    def wait(self, seconds: float) -> bool:
        return self.event.wait(seconds)


def alive_services(session: zenoh.Session, bus: BusConfig) -> set[str]:
    """The services whose liveliness token is on the bus now."""
    return {str(reply.ok.key_expr).rsplit("/", 1)[-1]
            for reply in session.liveliness().get(bus.key("alive/*"), timeout=1.0) if reply.ok is not None}


def wait_for_alive(session: zenoh.Session, bus: BusConfig, services: list[str], timeout: float = 20.0,
                   stopper: Stopper | None = None) -> bool:
    """Block until every named service has its liveliness token on the bus."""
    deadline = time.monotonic() + timeout
    want = set(services)
    while time.monotonic() < deadline and not (stopper and stopper.stopped):
        if want <= alive_services(session, bus):
            return True
        time.sleep(0.05)
    return False


class Presence:
    """Which services are alive, from their liveliness tokens (kept current by a subscriber)."""

    def __init__(self, session, bus: BusConfig):
        self._alive: set[str] = set()
        self._lock = threading.Lock()
        self._sub = session.liveliness().declare_subscriber(bus.key("alive/*"), self._on, history=True)

    def _on(self, sample) -> None:
        name = str(sample.key_expr).rsplit("/", 1)[-1]
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self._alive.add(name)
            else:
                self._alive.discard(name)

    def __contains__(self, name: str) -> bool:
        with self._lock:
            return name in self._alive

    def wait(self, name: str, timeout: float, stopper: "Stopper | None" = None) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not (stopper and stopper.stopped):
            if name in self:
                return True
            time.sleep(0.02)
        return name in self

    def close(self) -> None:
        self._sub.undeclare()


def setup_logging(service: str, level: str = "INFO") -> logging.Logger:
    logging.basicConfig(level=getattr(logging, level.upper(), logging.INFO),
                        format=f"%(asctime)s {service} %(levelname)s %(message)s")
    return logging.getLogger(f"polartrack.{service}")


class Inbox:
    """Zenoh callbacks only append here (no work in the callback); the service's main thread
    waits on it. Each named box is a deque; a box with ``maxlen`` drops its oldest entry when
    full (counted in ``dropped``), so a slow consumer never grows a queue without bound."""

    def __init__(self):
        from collections import deque

        self._deque = deque
        self.cv = threading.Condition()
        self.boxes: dict[str, object] = {}
        self.dropped: dict[str, int] = {}
        self._closed: set[str] = set()

    def callback(self, name: str, maxlen: int | None = None):
        box = self._deque(maxlen=maxlen)
        self.boxes[name] = box
        self.dropped[name] = 0

        def put(item) -> None:
            with self.cv:
                if name in self._closed:
                    return
                if box.maxlen is not None and len(box) == box.maxlen:
                    self.dropped[name] += 1
                box.append(item)
                self.cv.notify_all()

        return put

    def close(self, name: str) -> None:
        """Empty box ``name`` and keep nothing more in it: a subscription undeclared may still
        deliver a sample or two already on Zenoh's threads, which would otherwise stay there unread."""
        with self.cv:
            self._closed.add(name)
            self.boxes[name].clear()

    def pop(self, name: str):
        with self.cv:
            box = self.boxes[name]
            return box.popleft() if box else None

    def pending(self, name: str) -> int:
        with self.cv:
            return len(self.boxes[name])

    def wait(self, timeout: float) -> bool:
        """Wait until any box has an entry (True) or the timeout passes (False)."""
        with self.cv:
            if any(self.boxes.values()):
                return True
            return self.cv.wait_for(lambda: any(self.boxes.values()), timeout)
