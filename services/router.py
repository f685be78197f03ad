"""Router service: the Zenoh router the launcher's services join, in a process of its own.

A separate process (not the launcher's) so that every process that maps the services' shared
memory has exited when the run ends, and their segment files can be removed (a process keeps the
segments it has used until it exits). Publishes its CPU on ``status/router`` every second.
Run: ``python -m services.router --mode router --listen tcp/127.0.0.1:PORT [--shared-memory]``.
"""

from __future__ import annotations

import logging

from pydantic import BaseModel, ConfigDict

from services import options
from services.bus import BusConfig, Counters, Stopper, open_session, publisher

log = logging.getLogger("polartrack.router")


class RouterSettings(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


def serve(bus: BusConfig, stopper: Stopper) -> Counters:
    c = Counters("router")
    with open_session(bus) as session:
        pub_status = publisher(session, bus.key("status/router"))
        log.info("router on %s", ", ".join(bus.listen))
        while not stopper.wait(1.0):
            pub_status.put(c.status().SerializeToString())
        pub_status.put(c.status(final=True).SerializeToString())
    return c


def main(argv: list[str] | None = None) -> int:
    bus, _, _ = options.start("router", __doc__, RouterSettings, argv)
    serve(bus, Stopper())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
