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


def run_config_json(run_id: str, source: str, init_box, settings, pace: str, multi=None) -> str:
    """The run's ``RunConfig`` as JSON (ingest parses it into the message): the source, the
    first box, the tracker settings (or a multi-target run), the seed, the pace, the versions."""
    run = {"run_id": run_id, "source": source, "init_box": [] if init_box is None else [float(v) for v in init_box],
           "settings_json": settings.model_dump_json(), "seed": settings.seed if multi is None else multi.seed,
           "versions_json": json.dumps(versions()), "pace": pace}
    if multi is not None:
        run["multi_json"] = multi.to_json()
    return json.dumps(run)
