"""What every service checks in a message before acting on it, and how a bad one is counted.

Pure logic (no bus code: no ``zenoh``, no ``services``), shared by every service shell and the
launcher:

- :class:`Invalid`: a message that fails a check, with a short machine-readable ``reason``;
- the checks: :func:`decode` (size cap per key, then protobuf), :func:`check_frame_info` with a
  per-stream :class:`FrameOrder` (finite, non-negative time; index and time monotonic; time not
  absurdly far ahead of the previous frame's; frame size within caps and constant; a finite,
  non-singular homography), :func:`check_estimate`, :func:`check_multi_estimate`,
  :func:`check_status`, :func:`check_image_size`, :func:`check_query`;
- who may speak on which key (:class:`Senders`): each run gives every service a random per-run
  id, carried with every message; a run accepts frames and infos only from its ingest,
  estimates only from its tracker, replies only from its detector. With no ids configured (a
  service started by hand) every sender is accepted;
- :class:`Rejects`: the count per key and reason, and :class:`RateLimitedLog`, at most one log
  line per key every ``period_s`` seconds (with the number suppressed meanwhile);
- :class:`Guard`: the three together, what a service shell holds.
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time
from dataclasses import dataclass

import numpy as np

from common.msgs.topics import speakers as topic_speakers

# -- caps -----------------------------------------------------------------------------------

MiB = 1 << 20

MAX_BYTES = {
    "frame/image": 32 * MiB,
    "detector/query": 32 * MiB,
    "detector/reply": 32 * MiB,
    "track/particles": 8 * MiB,
    "track/annotations": 8 * MiB,
    "template": 4 * MiB,
    "track/multi_estimate": 4 * MiB,
    "run/config": 4 * MiB,
}
"""Largest payload accepted on a key (bytes); other keys (infos, estimates, statuses, health):
:data:`DEFAULT_MAX_BYTES`. A 1280x720 RGB frame is 2.7 MB, a 4K one 24.9 MB."""

DEFAULT_MAX_BYTES = 1 * MiB

MAX_IMAGE_SIDE = 8192
MAX_IMAGE_PIXELS = 3840 * 2160
"""Frame sizes accepted (a 4K frame at most)."""

MAX_HYPOTHESES = 32_768
"""Rows of an AT / GRID / PEAK / TEMPLATE query at most (a filter asks for its particles times
its candidates: 1,500 with 500 particles and 3 candidates; 100,000 held the detector 3.3 s)."""

MAX_BOXES = 1_000_000
"""Boxes of a HISTOGRAMS / SIMILARITY query at most (the gates' candidate grids: thousands)."""

MAX_CLIENT_CHARS = 64

MAX_TIME_JUMP_S = 60.0
"""A frame more than this per index step after the previous frame of its stream is rejected (a
FrameInfo 1e6 s ahead put the estimate 1e7 px off). Per index step: after frames that were
rejected (or skipped), the next good one is that many steps on, and may be that much later."""

MIN_EQUILIBRATED_DET = 1e-9
"""A homography whose determinant, once its columns and then its rows are scaled to unit length,
is below this is singular (1 for a rotation; 0.15-0.7 for the synthetic scene's cameras)."""

MAX_FRAME_INDEX = 1 << 40


class Invalid(ValueError):
    """A message that fails a check; ``reason`` is a short name (counted per key and reason)."""

    def __init__(self, reason: str, detail: str = ""):
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason
        self.detail = detail


def max_bytes(key: str) -> int:
    return MAX_BYTES.get(key, DEFAULT_MAX_BYTES)


def decode(cls, data: bytes, key: str, limit: int | None = None):
    """``cls`` decoded from ``data``, after the key's size cap; Invalid otherwise."""
    cap = max_bytes(key) if limit is None else limit
    if len(data) > cap:
        raise Invalid("too_large", f"{len(data)} bytes (at most {cap})")
    try:
        return cls.FromString(data)
    except Exception as exc:  # noqa: BLE001 - protobuf raises DecodeError and others
        raise Invalid("undecodable", f"not a {cls.__name__}: {type(exc).__name__}") from None


def finite(reason: str = "not_finite", **values) -> None:
    for name, v in values.items():
        if not math.isfinite(float(v)):
            raise Invalid(reason, f"{name}={v}")


def check_homography(values) -> None:
    """Empty (none known) or 9 finite values of a non-singular, well-conditioned matrix."""
    n = len(values)
    if n == 0:
        return
    if n != 9:
        raise Invalid("bad_homography", f"{n} values, expected 9")
    h = np.asarray(values, float).reshape(3, 3)
    if not np.all(np.isfinite(h)):
        raise Invalid("bad_homography", "NaN or infinite entries")
    if not np.any(h):
        raise Invalid("bad_homography", "all zero")
    # Singular up to the units of either plane: the determinant once every column (the source
    # plane's axes) and then every row (the image's) has unit length. The plain condition
    # number is no test: a ground plane in metres kilometres from its origin gives 1e8-1e12
    # for a perfectly good camera (the 30-minute scene's infos were all refused on that).
    cols = np.linalg.norm(h, axis=0)
    if np.any(cols == 0.0):
        raise Invalid("bad_homography", "singular (a zero column)")
    hc = h / cols
    rows = np.linalg.norm(hc, axis=1, keepdims=True)
    if np.any(rows == 0.0) or abs(float(np.linalg.det(hc / rows))) < MIN_EQUILIBRATED_DET:
        raise Invalid("bad_homography", "singular")


def check_image_size(width: int, height: int) -> None:
    if not (0 < width <= MAX_IMAGE_SIDE and 0 < height <= MAX_IMAGE_SIDE and width * height <= MAX_IMAGE_PIXELS):
        raise Invalid("bad_size", f"{width}x{height} (sides 1-{MAX_IMAGE_SIDE}, at most {MAX_IMAGE_PIXELS} pixels)")


class FrameOrder:
    """One stream's frames: index strictly increasing, time never going back nor jumping more
    than ``max_jump_s`` per index step ahead, the same frame size throughout. :meth:`check` raises Invalid and
    changes nothing; :meth:`accept` records a frame that passed."""

    def __init__(self, max_jump_s: float = MAX_TIME_JUMP_S):
        self.max_jump_s = max_jump_s
        self.index: int | None = None
        self.time_s: float | None = None
        self.capture_ns: int | None = None
        self.size: tuple[int, int] | None = None
        self.ended = False

    def check(self, index: int, time_s: float | None = None, capture_ns: int | None = None,
              size: tuple[int, int] | None = None) -> None:
        if self.ended:
            raise Invalid("after_end_of_stream", f"frame {index}")
        if not 0 <= index <= MAX_FRAME_INDEX:
            raise Invalid("bad_index", str(index))
        if self.index is not None and index <= self.index:
            raise Invalid("index_not_increasing", f"{index} after {self.index}")
        if time_s is not None:
            finite("bad_time", time_s=time_s)
            if time_s < 0:
                raise Invalid("bad_time", f"time_s={time_s}")
            if self.time_s is not None:
                if time_s < self.time_s:
                    raise Invalid("time_backwards", f"{time_s} after {self.time_s}")
                if time_s - self.time_s > self.max_jump_s * self._steps(index):
                    raise Invalid("time_jump", f"{time_s - self.time_s:.3g} s after the previous frame")
        if capture_ns is not None:
            if capture_ns < 0:
                raise Invalid("bad_time", f"capture_ns={capture_ns}")
            if self.capture_ns is not None:
                if capture_ns < self.capture_ns:
                    raise Invalid("time_backwards", f"capture_ns {capture_ns} after {self.capture_ns}")
                if (capture_ns - self.capture_ns) * 1e-9 > self.max_jump_s * self._steps(index):
                    raise Invalid("time_jump", f"capture time {(capture_ns - self.capture_ns) * 1e-9:.3g} s ahead")
        if size is not None and self.size is not None and tuple(size) != self.size:
            raise Invalid("size_changed", f"{size[0]}x{size[1]} after {self.size[0]}x{self.size[1]}")

    def _steps(self, index: int) -> int:
        return 1 if self.index is None else max(1, index - self.index)

    def accept(self, index: int, time_s: float | None = None, capture_ns: int | None = None,
               size: tuple[int, int] | None = None) -> None:
        self.index = index
        self.time_s = time_s if time_s is not None else self.time_s
        self.capture_ns = capture_ns if capture_ns is not None else self.capture_ns
        self.size = tuple(size) if size is not None else self.size


def check_frame_info(info, order: FrameOrder) -> None:
    """A FrameInfo a tracker can step on (or an end of stream after the last frame); on success
    ``order`` moves on. Raises Invalid."""
    index = int(info.index)
    if info.end_of_stream:
        if order.ended:
            raise Invalid("after_end_of_stream", "a second end of stream")
        if not 0 <= index <= MAX_FRAME_INDEX or (order.index is not None and index <= order.index):
            raise Invalid("bad_end_of_stream", f"index {index} after frame {order.index}")
        order.ended = True
        return
    size = (int(info.width), int(info.height))
    check_image_size(*size)
    order.check(index, float(info.time_s), int(info.capture_ns), size)
    check_homography(info.homography)
    order.accept(index, float(info.time_s), int(info.capture_ns), size)


def check_estimate(e, max_index: int | None = None) -> None:
    """An Estimate with finite numbers, about a frame that exists (``max_index``: the newest
    frame published or seen, when known)."""
    if e.frame_index < 0 or (max_index is not None and e.frame_index > max_index):
        raise Invalid("unknown_frame", f"frame {e.frame_index} (newest {max_index})")
    finite(x=e.x, y=e.y, time_s=e.time_s, latency_ms=e.latency_ms, step_ms=e.step_ms, box_dx=e.box_dx,
           box_dy=e.box_dy)
    if e.frames_skipped < 0:
        raise Invalid("bad_count", f"frames_skipped={e.frames_skipped}")


def check_multi_estimate(e, max_index: int | None = None) -> None:
    if e.frame_index < 0 or (max_index is not None and e.frame_index > max_index):
        raise Invalid("unknown_frame", f"frame {e.frame_index} (newest {max_index})")
    finite(latency_ms=e.latency_ms, step_ms=e.step_ms)
    if not 0 <= e.targets <= 1000 or e.frames_skipped < 0:
        raise Invalid("bad_count", f"targets={e.targets}")


def check_status(st, key: str) -> None:
    """A ServiceStatus on ``status/<service>`` from that service, with sane counters."""
    want = key.rsplit("/", 1)[-1]
    if st.service != want:
        raise Invalid("wrong_service", f"{st.service!r} on {key}")
    finite(cpu_s=st.cpu_s)
    if st.cpu_s < 0 or min(st.received, st.published, st.malformed, st.dropped, st.errors) < 0:
        raise Invalid("bad_count", "negative counter")


def check_query(q, part_kinds=()) -> None:
    """A ScoreQuery within the caps (the detector checks the rest: sizes against count, NaNs)."""
    if len(q.client) > MAX_CLIENT_CHARS:
        raise Invalid("bad_client", f"{len(q.client)} characters (at most {MAX_CLIENT_CHARS})")
    cap = MAX_BOXES if q.kind in part_kinds else MAX_HYPOTHESES
    if not 0 <= q.count <= cap:
        raise Invalid("too_many_hypotheses", f"{q.count} (at most {cap})")
    if not 0 <= q.frame_index <= MAX_FRAME_INDEX:
        raise Invalid("bad_index", str(q.frame_index))


# -- who may speak ----------------------------------------------------------------------------

SPEAKERS = topic_speakers()
"""Key suffix -> the services of the run that publish on it, from the pipeline's graph
(:mod:`common.msgs.topics`; a query's ``KEY/query``: who may ask); ``status/<s>`` and
``health/<s>``: service ``s``."""


def speakers(key: str) -> tuple[str, ...]:
    if key.startswith(("status/", "health/")):
        return (key.split("/", 1)[1],)
    return SPEAKERS.get(key, ())


class Senders:
    """The run's per-service ids (``{service: id}``). Empty: nothing to check (every sender is
    accepted, as when a service is started by hand)."""

    def __init__(self, ids: dict[str, str] | None = None):
        self.ids = dict(ids or {})

    @property
    def enforced(self) -> bool:
        return bool(self.ids)

    def id(self, service: str) -> str:
        return self.ids.get(service, "")

    def check(self, key: str, sender: str | None) -> None:
        """Invalid("foreign_sender") unless ``sender`` is one of the run's services that speak on ``key``."""
        if not self.ids:
            return
        allowed = {self.ids[s] for s in speakers(key) if s in self.ids}
        if not sender or sender not in allowed:
            raise Invalid("foreign_sender", f"{sender or 'no sender id'} on {key}")


# -- counting and logging -------------------------------------------------------------------

class RateLimitedLog:
    """At most one line per key every ``period_s`` seconds; the next line says how many were
    suppressed meanwhile."""

    def __init__(self, logger: logging.Logger, period_s: float = 5.0, clock=time.monotonic):
        self.logger, self.period_s, self.clock = logger, period_s, clock
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}
        self._lock = threading.Lock()

    def warning(self, key: str, message: str) -> bool:
        """Log ``message`` for ``key`` unless one was logged less than a period ago (True if logged)."""
        now = self.clock()
        with self._lock:
            if key not in self._last and len(self._last) >= 256:
                key = "(other)"
            last = self._last.get(key)
            if last is not None and now - last < self.period_s:
                self._suppressed[key] = self._suppressed.get(key, 0) + 1
                return False
            self._last[key] = now
            n = self._suppressed.pop(key, 0)
        self.logger.warning("%s%s", message, f" ({n} more like it on {key} not logged)" if n else "")
        return True


class Rejects:
    """Messages dropped, per key and reason (thread-safe). At most ``max_keys`` keys are told
    apart (keys beyond, e.g. random ones an attacker makes up, are counted under ``(other)``)."""

    def __init__(self, max_keys: int = 64):
        self._lock = threading.Lock()
        self._counts: dict[str, dict[str, int]] = {}
        self.max_keys = max_keys

    def add(self, key: str, reason: str, n: int = 1) -> None:
        with self._lock:
            if key not in self._counts and len(self._counts) >= self.max_keys:
                key = "(other)"
            reason = reason[:40]
            by_reason = self._counts.setdefault(key, {})
            by_reason[reason] = by_reason.get(reason, 0) + n

    def snapshot(self) -> dict[str, dict[str, int]]:
        with self._lock:
            return {k: dict(v) for k, v in self._counts.items()}

    def total(self, reason: str | None = None) -> int:
        with self._lock:
            return sum(n for v in self._counts.values() for r, n in v.items() if reason is None or r == reason)

    def to_json(self) -> bytes:
        return json.dumps(self.snapshot(), sort_keys=True).encode()


def parse_rejects(data: bytes) -> dict[str, dict[str, int]]:
    """A :meth:`Rejects.to_json` payload (``health/<service>``); Invalid when it is not one."""
    if len(data) > DEFAULT_MAX_BYTES:
        raise Invalid("too_large", f"{len(data)} bytes")
    try:
        d = json.loads(data)
    except (ValueError, UnicodeDecodeError):
        raise Invalid("undecodable", "not JSON") from None
    if not (isinstance(d, dict) and all(isinstance(k, str) and isinstance(v, dict) for k, v in d.items())
            and all(isinstance(r, str) and isinstance(n, int) and n >= 0 for v in d.values() for r, n in v.items())):
        raise Invalid("undecodable", "not a {key: {reason: count}} table")
    return d


@dataclass
class Guard:
    """A service's checks: who may speak (``senders``), what was dropped (``rejects``), a log at
    a bounded rate, and a hook called once per rejected message (the service's ``malformed``
    counter)."""

    service: str
    senders: Senders
    logger: logging.Logger
    on_reject: object = None
    period_s: float = 5.0

    def __post_init__(self):
        self.rejects = Rejects()
        self.log = RateLimitedLog(self.logger, self.period_s)

    def reject(self, key: str, exc: Invalid | str, detail: str = "") -> None:
        reason = exc.reason if isinstance(exc, Invalid) else str(exc)
        detail = exc.detail if isinstance(exc, Invalid) else detail
        self.rejects.add(key, reason)
        if self.on_reject is not None:
            self.on_reject(key, reason)
        self.log.warning(key, f"dropped a message on {key}: {reason}{': ' + detail if detail else ''}")

    def decode(self, key: str, cls, data: bytes, sender: str | None, check=None, *args):
        """The message, or None (counted and logged) when its sender is not the run's, it is too
        large, does not decode or fails ``check(msg, *args)``."""
        try:
            self.senders.check(key, sender)
            msg = decode(cls, data, key)
            if check is not None:
                check(msg, *args)
            return msg
        except Invalid as exc:
            self.reject(key, exc)
            return None

    def accept(self, key: str, sender: str | None, size: int | None = None) -> bool:
        """Sender and size checks only (payloads decoded elsewhere); False (counted) if either fails."""
        try:
            self.senders.check(key, sender)
            if size is not None and size > max_bytes(key):
                raise Invalid("too_large", f"{size} bytes (at most {max_bytes(key)})")
            return True
        except Invalid as exc:
            self.reject(key, exc)
            return False


class Counters:
    """A service's counters (thread-safe), published as ServiceStatus."""

    def __init__(self, service: str):
        self.service = service
        self._lock = threading.Lock()
        self.values = {"received": 0, "published": 0, "malformed": 0, "dropped": 0, "errors": 0}

    def add(self, name: str, n: int = 1) -> None:
        with self._lock:
            self.values[name] += n

    def __getitem__(self, name: str) -> int:
        return self.values[name]

    def status(self, final: bool = False):
        import psutil

        from common.msgs import ServiceStatus

        cpu = psutil.Process().cpu_times()
        with self._lock:
            return ServiceStatus(service=self.service, cpu_s=cpu.user + cpu.system, final=final, **self.values)
