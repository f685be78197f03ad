# syntax=docker/dockerfile:1
# PolarTrack services image: the project installed from uv.lock (no dev dependencies) in
# /app/.venv, which is on PATH. Every service runs from it as `python -m services.<name>`
# (see compose.yaml); the default command prints the CLI's help.
#
#   docker build -t polartrack .
#   docker run --rm polartrack                      # polartrack --help
#   docker run --rm polartrack python -m services.ingest --help

ARG PYTHON_VERSION=3.11
ARG UV_VERSION=0.13.9

FROM ghcr.io/astral-sh/uv:${UV_VERSION} AS uv

FROM python:${PYTHON_VERSION}-slim

COPY --from=uv /uv /uvx /usr/local/bin/

ENV UV_COMPILE_BYTECODE=1 \
    UV_LINK_MODE=copy \
    UV_PYTHON_DOWNLOADS=never \
    UV_PROJECT_ENVIRONMENT=/app/.venv

WORKDIR /app

# Dependencies first (cached while pyproject.toml and uv.lock are unchanged), then the project.
RUN --mount=type=cache,target=/root/.cache/uv \
    --mount=type=bind,source=uv.lock,target=uv.lock \
    --mount=type=bind,source=pyproject.toml,target=pyproject.toml \
    uv sync --locked --no-dev --no-install-project

COPY . /app

RUN --mount=type=cache,target=/root/.cache/uv \
    uv sync --locked --no-dev \
 && /app/.venv/bin/python -m compileall -q common services

# Run as an unprivileged user. /app/recordings belongs to it, so the named volume mounted
# there (compose.yaml) starts out writable by it.
RUN useradd --create-home --uid 1000 app \
 && mkdir -p /app/recordings \
 && chown app:app /app/recordings

ENV PATH="/app/.venv/bin:${PATH}" \
    PYTHONUNBUFFERED=1 \
    NUMBA_CACHE_DIR=/tmp/numba-cache \
    MPLCONFIGDIR=/tmp/matplotlib

USER app

CMD ["polartrack", "--help"]
