"""Settings files written from the settings models: each key with its model's documentation.

- :func:`run_file`: the run file (:class:`common.settings.RunSpec`) that compose's ingest and
  tracker read with ``--run`` (``deploy/run.toml``; ``polartrack config run``).
- :func:`service_file`: one service's settings (``polartrack config dump SERVICE``: every key
  with its default; ``--deploy``: the compose deployment's file, ``deploy/SERVICE.toml``).

The compose deployment's own values are declared once, in :data:`DEPLOYMENT`;
``polartrack config deploy`` writes every ``deploy/*.toml`` from them, and
``tests/test_compose.py`` checks that the committed files are what it writes.
"""

from __future__ import annotations

import textwrap
from typing import Any

import tomlkit
from pydantic import BaseModel

SERVICES = ("ingest", "detector", "tracker", "recorder", "viewer")
"""The project's services in compose.yaml (each a ``python -m services.NAME``), besides the router."""

ROUTER = "tls/zenoh-router:7447"
"""The Compose router's endpoint (service ``zenoh-router``, deploy/zenoh-router.json5)."""

CERTS = "/app/certs"
"""deploy/certs as the containers see it (tools/gen_certs.sh writes it)."""

RUN_FILE = "/app/deploy/run.toml"
"""The run file as the containers see it (compose.yaml gives it to ingest and the tracker)."""

DEPLOYMENT: dict[str, dict[str, Any]] = {
    "ingest": {"wait_for": ["detector", "tracker", "recorder"], "wait_timeout_s": 120.0},
    "detector": {},
    "tracker": {},
    "recorder": {"out": "/app/recordings/compose.mcap"},
    "viewer": {"out": "/app/recordings/compose.rrd"},
}
"""What the compose deployment sets beyond each model's defaults (its source, box and settings
are in the run file): ingest waits for the services that must not miss a frame (containers may
start slowly: image pull, first import); the outputs go to the ``recordings`` volume."""

WIDTH = 100


def model_class(service: str) -> type[BaseModel]:
    """The settings model of ``service`` (its flags and TOML keys)."""
    from importlib import import_module

    names = {"ingest": "IngestSettings", "detector": "DetectorSettings", "tracker": "TrackerServiceSettings",
             "recorder": "RecorderSettings", "viewer": "ViewerSettings"}
    if service not in names:
        raise ValueError(f"no service {service!r}; one of {', '.join(SERVICES)}")
    return getattr(import_module(f"services.{service}"), names[service])


def _comment(container, text: str | None) -> None:
    for line in textwrap.wrap(" ".join((text or "").split()), WIDTH - 2):
        container.add(tomlkit.comment(line))


def _submodel(model: type[BaseModel] | None, key: str, table_models: dict | None) -> type[BaseModel] | None:
    """The model documenting the table ``key`` of ``model``: the one ``table_models`` names for it,
    or the field's own model type; None when neither."""
    if table_models and key in table_models:
        return table_models[key]
    field = model.model_fields.get(key) if model is not None else None
    ann = getattr(field, "annotation", None)
    for cand in (ann, *getattr(ann, "__args__", ())):
        if isinstance(cand, type) and issubclass(cand, BaseModel):
            return cand
    return None


def _fill(container, model: type[BaseModel] | None, values: dict, table_models: dict | None = None) -> None:
    """Keys first, then tables (TOML's order), each after its documentation; ``table_models`` names
    the model that documents a top-level table whose field is a plain dict (or the bus's)."""
    fields = model.model_fields if model is not None else {}
    scalars = {k: v for k, v in values.items() if not isinstance(v, dict)}
    tables = {k: v for k, v in values.items() if isinstance(v, dict)}
    for key, value in scalars.items():
        if key in fields:
            _comment(container, fields[key].description)
        if value is None:  # TOML has no null: say it is unset (read back, the key gets its default)
            default = fields[key].get_default(call_default_factory=True) if key in fields else None
            if default is not None:
                raise ValueError(f"{key} = None cannot be written in TOML (read back, it would be {default!r})")
            container.add(tomlkit.comment(f"{key}: unset"))
            continue
        container.add(key, list(value) if isinstance(value, tuple) else value)
    for key, value in tables.items():
        table = tomlkit.table()
        if key in fields:
            _comment(table, fields[key].description)
        _fill(table, _submodel(model, key, table_models), value)
        container.add(key, table)


def document(header: str, model: type[BaseModel], values: dict, table_models: dict | None = None) -> str:
    """``values`` as TOML under the comment ``header``, each key after its field's description."""
    doc = tomlkit.document()
    for line in header.strip().splitlines():
        doc.add(tomlkit.comment(line))
    doc.add(tomlkit.nl())
    _fill(doc, model, values, table_models)
    return tomlkit.dumps(doc)


def run_file(spec, command: str) -> str:
    """The run file of ``spec`` (a :class:`common.settings.RunSpec`): its keys that are set,
    each documented, and the settings overrides as a ``[settings]`` table; ``command`` wrote it."""
    from common.settings import RunSpec, TrackerSettings

    values = spec.model_dump(exclude_none=True)
    if not values.get("settings"):
        values.pop("settings", None)
    header = (
        "What the run tracks (common.settings.RunSpec): compose's ingest and tracker both read this\n"
        f"one file (--run). Written by `{command}`.\n"
        "The tracker's settings are the source's profile (the synthetic scene's calibration, or the\n"
        "real-footage one at fps); replace any of them in a [settings] table, e.g.\n"
        "  [settings.scale]\n"
        "  mode = \"search\"")
    return document(header, RunSpec, values, {"settings": TrackerSettings})


def bus_values(service: str) -> dict:
    """A compose service's bus: a Zenoh client of the router over mutual TLS with its own
    certificate (the router's access control matches its common name), no scouting."""
    return {"stream": "default", "mode": "client", "connect": [ROUTER], "multicast_scouting": False,
            "tls": {"root_ca_certificate": f"{CERTS}/ca.pem", "certificate": f"{CERTS}/{service}.pem",
                    "private_key": f"{CERTS}/{service}.key"}}


def service_file(service: str, deploy: bool) -> str:
    """``service``'s settings as TOML: with ``deploy``, the compose deployment's file (the keys
    of :data:`DEPLOYMENT` and the bus); without, every key with its default."""
    from services.bus import BusConfig

    model = model_class(service)
    run = " --run " + RUN_FILE if service in ("ingest", "tracker") else ""
    if deploy:
        values = dict(DEPLOYMENT[service]) | {"bus": bus_values(service)}
        header = (f"The {service} service in compose.yaml:\n"
                  f"  python -m services.{service} --config /app/deploy/{service}.toml{run} --ids {CERTS}/ids.json\n"
                  "Same keys as its flags (a flag after --config wins). Generated: do not edit by hand but change\n"
                  "services/deploy.py's DEPLOYMENT and run `uv run polartrack config deploy` (tests/test_compose.py\n"
                  "checks that the files are what it writes).")
    else:
        values = {k: f.get_default(call_default_factory=True) for k, f in model.model_fields.items()
                  if not f.is_required()}
        values = {k: (v.model_dump() if isinstance(v, BaseModel) else v) for k, v in values.items()}
        if service == "tracker":  # the filter's settings: the source's profile, in the run file
            values.pop("settings")
        values["bus"] = BusConfig().model_dump(exclude_none=True)
        header = (f"python -m services.{service}: every key with its default (the flags have the same names).\n"
                  "Required keys without a default: "
                  + (", ".join(k for k, f in model.model_fields.items() if f.is_required()) or "none")
                  + ("\nsettings (the filter's, common.settings.TrackerSettings): the source's profile, with a run file's "
                     "[settings]\non top (uv run polartrack config run --help)" if service == "tracker" else ""))
    return document(header, model, values, {"bus": BusConfig})


def deploy_files(run_spec) -> dict[str, str]:
    """Every ``deploy/*.toml``: ``run.toml`` and one per service."""
    out = {"run.toml": run_file(run_spec, "uv run polartrack config deploy")}
    out |= {f"{s}.toml": service_file(s, deploy=True) for s in SERVICES}
    return out


def compose_run_spec():
    """The compose deployment's run: the synthetic scene from its first true box."""
    from common.settings import RunSpec
    from common.sources import open_source

    source = open_source("synthetic:0")
    # to a millionth of a pixel: the scene's box differs in its last bits between CPUs (their vector
    # maths), and the written file must be the same on every machine
    box = tuple(round(float(v), 6) for v in source.frame(0).truth.box)
    return RunSpec(source="synthetic:0", init_box=box, fps=source.fps)
