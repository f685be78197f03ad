"""Shared fixtures.

- ``synthetic_pipeline``: the launcher's multi-process pipeline on a synthetic source, from its
  first true box with the source's profile, writing under the test's ``tmp_path``.

Tests that start services as processes on a bus are marked ``slow`` (``uv run pytest -m "not
slow"`` leaves them out); the full ``uv run pytest`` is what CI runs.
"""

from __future__ import annotations

import pytest


@pytest.fixture
def synthetic_pipeline(tmp_path):
    """``make(source, frames, seed=None, settings=None, **kw) -> Pipeline`` (not yet started: use
    it as a context manager). ``seed`` goes to the profile (``profile_for(source, seed=...)``);
    ``settings`` replaces the profile; ``kw`` goes to :class:`services.launcher.Pipeline`
    (``viewer`` defaults to False)."""
    from common.settings import profile_for
    from common.sources import open_source
    from services.launcher import Pipeline

    def make(source: str, frames: int, seed: int | None = None, settings=None, **kw):
        src = open_source(source, n_frames=frames)
        if settings is None:
            settings = profile_for(src) if seed is None else profile_for(src, seed=seed)
        kw.setdefault("viewer", False)
        kw.setdefault("log_dir", tmp_path)
        return Pipeline(source, src.frame(0).truth.box, settings, out_dir=tmp_path, frames=frames, **kw)

    return make
