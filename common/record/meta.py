"""What a recording says of its run: the ``RunConfig`` that ingest publishes before the first
frame and the recorder keeps as the MCAP's ``run`` metadata (replay reads it back)."""

from __future__ import annotations

import json
import sys


def versions() -> dict[str, str]:
    """The versions of Python and of the packages that decide a run's numbers."""
    from importlib.metadata import PackageNotFoundError, version

    out = {"python": sys.version.split()[0]}
    for pkg in ("polartrack", "numpy", "dtcwt", "opencv-python-headless", "eclipse-zenoh", "mcap", "rerun-sdk", "numba"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            pass
    return out


MAX_EXACT_INT = 2**53
"""Numbers in a ``google.protobuf.Struct`` are doubles: integers up to this are exact."""


def run_config_json(run_id: str, source: str, init_box, settings, pace: str, multi=None) -> str:
    """The run's ``RunConfig`` in protobuf's JSON form (ingest parses it into the message): the
    source, the first box, the tracker settings (or a multi-target run) as typed fields, the
    seed, the pace, the versions."""
    run = {"run_id": run_id, "source": source, "init_box": [] if init_box is None else [float(v) for v in init_box],
           "settings": settings.model_dump(mode="json"), "seed": settings.seed if multi is None else multi.seed,
           "versions": versions(), "pace": pace}
    if multi is not None:
        run["multi"] = json.loads(multi.to_json())
    return json.dumps(run)


def _exact(value):
    """A Struct's numbers back as the JSON they were: integral doubles as integers."""
    if isinstance(value, dict):
        return {k: _exact(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_exact(v) for v in value]
    if isinstance(value, float) and value.is_integer() and abs(value) <= MAX_EXACT_INT:
        return int(value)
    return value


def run_metadata(raw: bytes) -> dict[str, str]:
    """The MCAP ``run`` metadata of a RunConfig message (what the recorder writes; MCAP metadata
    values are text): every field as text, the settings, the versions and a multi-target run as
    JSON under ``settings_json``, ``versions_json`` and ``multi_json``, whether the message carried
    them typed or (before 2026-12) as JSON text."""
    from google.protobuf.json_format import MessageToDict

    from common.msgs import RunConfig

    cfg = RunConfig.FromString(raw)
    d = MessageToDict(cfg, preserving_proto_field_name=True, always_print_fields_with_no_presence=True)
    for typed, text in (("settings", "settings_json"), ("versions", "versions_json"), ("multi", "multi_json")):
        value = d.pop(typed, None)
        if value and not d.get(text):
            d[text] = json.dumps(_exact(value))
    return {k: v if isinstance(v, str) else json.dumps(v) for k, v in d.items()}
