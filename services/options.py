"""Flags and TOML config of a service, validated with clear one-line messages.

Every service takes the bus flags (``--stream --mode --listen --connect --shared-memory``), its own flags, and an
optional ``--config FILE.toml`` whose keys are the same names (flags given on the command line
win). Errors exit with status 2 and say which key is wrong and why.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tomllib
from typing import TypeVar

from pydantic import BaseModel, ValidationError

from services.bus import BusConfig

M = TypeVar("M", bound=BaseModel)


def add_bus_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", metavar="FILE.toml", help="TOML (or .json) file with the same keys as the flags")
    p.add_argument("--stream", help="pipeline namespace (keys polartrack/<stream>/...)")
    p.add_argument("--mode", choices=["peer", "client", "router"], help="Zenoh mode")
    p.add_argument("--listen", action="append", metavar="ENDPOINT", help="Zenoh endpoint to listen on (repeatable)")
    p.add_argument("--connect", action="append", metavar="ENDPOINT", help="Zenoh endpoint to connect to (repeatable)")
    p.add_argument("--shared-memory", dest="shared_memory", action="store_const", const=True,
                   help="Zenoh shared memory for the frame images (the launcher's processes use it)")
    p.add_argument("--ids", metavar="FILE.json", help="the run's sender ids ({service: id}; the launcher writes it): "
                   "this service speaks with its own and accepts each key only from the run's services")
    p.add_argument("--log-level", default="INFO", help="logging level")
    p.add_argument("--threads", type=int, default=1, metavar="N",
                   help="OpenCV threads of this process (0: its default, a thread per core)")
    p.add_argument("--nice", type=int, default=0, metavar="N",
                   help="lower this process's scheduling priority by N (the launcher runs the viewer at 19)")


def fail(service: str, message: str) -> None:
    print(f"{service}: error: {message}", file=sys.stderr)
    raise SystemExit(2)


def lower_priority(nice: int) -> None:
    """Lower the priority of the calling thread, and of the threads it starts from now on, by
    ``nice`` (Linux: the nice value is per thread, and a new thread inherits its creator's)."""
    if nice > 0:
        os.nice(nice)


def flag_type(annotation):
    """argparse keywords for a settings field's type; None for a field that only a config file
    sets (nested models, tables)."""
    import types
    import typing

    args = [a for a in typing.get_args(annotation) if a is not type(None)]
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        if len(args) != 1:
            return None
        return flag_type(args[0])
    origin = typing.get_origin(annotation)
    if origin is typing.Literal:
        return {"choices": list(args)}
    if origin is tuple and args and all(a is float for a in args if a is not Ellipsis):
        n = None if Ellipsis in args else len(args)

        def floats(text: str):
            values = tuple(float(v) for v in text.split(","))
            if n is not None and len(values) != n:
                raise argparse.ArgumentTypeError(f"expected {n} comma-separated numbers")
            return values

        return {"type": floats, "metavar": ",".join(["N"] * (n or 2))}
    if origin is list and args == [str]:
        return {"type": lambda t: [v for v in t.split(",") if v], "metavar": "A,B"}
    if annotation is bool:
        return {"action": argparse.BooleanOptionalAction}
    if annotation in (int, float, str):
        return {"type": annotation}
    return None


def field_help(field) -> str | None:
    """A settings field's description as one paragraph (an attribute docstring keeps its line breaks)."""
    return None if field.description is None else " ".join(field.description.split())


def add_model_flags(p: argparse.ArgumentParser, model: type[BaseModel], skip: tuple[str, ...] = ()) -> list[str]:
    """A flag for every field of ``model`` that a command line can hold (``--max-lag-frames N`` for
    ``max_lag_frames``; booleans ``--x / --no-x``), with the field's description as its help; the
    nested ones (tables) only in ``--config``. Returns the keys, for :func:`load`."""
    keys = []
    for name, field in model.model_fields.items():
        kw = None if name in skip else flag_type(field.annotation)
        if kw is None:
            continue
        p.add_argument("--" + name.replace("_", "-"), dest=name, default=None, help=field_help(field), **kw)
        keys.append(name)
    return keys


def start(service: str, doc: str | None, model: type[M], argv: list[str] | None, run=None,
          nice_later: bool = False) -> tuple[BusConfig, M, argparse.Namespace]:
    """Every service's start: its flags (the bus's, one a settings field, ``--run`` when the
    service reads the run file through ``run``), the settings validated (:func:`load`), logging
    set up. Returns the bus, the settings and the parsed flags."""
    p = argparse.ArgumentParser(prog=f"python -m services.{service}", description=doc)
    add_bus_arguments(p)
    keys = add_model_flags(p, model)
    if run is not None:
        add_run_argument(p)
    args = p.parse_args(argv)
    bus, cfg = load(service, args, model, keys, nice_later=nice_later, run=run)
    from services.bus import setup_logging

    setup_logging(service, args.log_level)
    return bus, cfg, args


def add_run_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--run", metavar="FILE.toml", help="what the run tracks (common.settings.RunSpec: source, "
                   "init_box, filter, settings; e.g. deploy/run.toml, written by `polartrack config run`)")


def read_table(service: str, flag: str, path: str) -> dict:
    """A TOML (or .json) file's table; a one-line error (exit 2) when it is missing or not valid."""
    try:
        with open(path, "rb") as fh:
            data = json.load(fh) if path.endswith(".json") else tomllib.load(fh)
    except FileNotFoundError:
        fail(service, f"{flag} {path}: no such file")
    except (tomllib.TOMLDecodeError, json.JSONDecodeError, UnicodeDecodeError) as exc:
        fail(service, f"{flag} {path}: not valid {'JSON' if path.endswith('.json') else 'TOML'} ({exc})")
    if not isinstance(data, dict):
        fail(service, f"{flag} {path}: expected a table of keys")
    return data


def load_run(service: str, path: str):
    """The run file (``--run``): a validated :class:`common.settings.RunSpec` and its resolved
    tracker settings; a one-line error naming the bad key otherwise."""
    from common.settings import RunSpec

    try:
        spec = RunSpec(**read_table(service, "--run", path))
        return spec, spec.tracker_settings()
    except ValidationError as exc:
        first = exc.errors()[0]
        fail(service, f"--run {path}: {'.'.join(str(p) for p in first['loc']) or 'run'}: {first['msg']} "
                      f"(got {first.get('input')!r})")
    except ValueError as exc:
        fail(service, f"--run {path}: {exc}")


def load(service: str, args: argparse.Namespace, model: type[M], keys: list[str],
         nice_later: bool = False, run=None) -> tuple[BusConfig, M]:
    """Merge the run file (``--run``, through ``run(spec, settings, path) -> keys``), the TOML
    file (if any) and the flags that were given, in that order, then validate both models.
    Also limits the process's OpenCV threads (``--threads``, see :mod:`services.threads`) and
    lowers its priority (``--nice``), unless ``nice_later``: then the service calls
    :func:`lower_priority` itself, once the threads that must keep their priority are up."""
    from services.threads import limit_threads

    limit_threads(getattr(args, "threads", 0) or 0)
    if not nice_later:
        lower_priority(getattr(args, "nice", 0))
    data: dict = {}
    if run is not None and getattr(args, "run", None):
        data = dict(run(*load_run(service, args.run), args.run))
    if args.config:
        data |= read_table(service, "--config", args.config)
    bus_data = dict(data.pop("bus", {}))
    for k in ("stream", "mode", "listen", "connect", "shared_memory"):
        v = getattr(args, k, None)
        if v is not None:
            bus_data[k] = v
    ids_file = getattr(args, "ids", None)
    if ids_file:
        try:
            with open(ids_file, "rb") as fh:
                bus_data["ids"] = json.load(fh)
        except (OSError, json.JSONDecodeError) as exc:
            fail(service, f"--ids {ids_file}: {exc}")
    svc_data = dict(data)
    for k in keys:
        v = getattr(args, k, None)
        if v is not None:
            svc_data[k] = v
    try:
        bus = BusConfig(**bus_data)
        cfg = model(**svc_data)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"]) or "config"
        fail(service, f"{where}: {first['msg']} (got {first.get('input')!r})")
    from services.bus import set_identity

    set_identity(bus.ids.get(service, ""))
    die_with_parent()
    return bus, cfg


def die_with_parent() -> None:
    """A service the launcher started (``POLARTRACK_PARENT_PID``) gets SIGTERM when the launcher
    dies, even by SIGKILL (Linux ``PR_SET_PDEATHSIG``), and exits at once if it is already gone:
    no orphan keeps running."""
    parent = os.environ.get("POLARTRACK_PARENT_PID")
    if not parent or not sys.platform.startswith("linux"):
        return
    try:
        import ctypes
        import signal

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, int(signal.SIGTERM), 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() != int(parent):
        raise SystemExit(1)
