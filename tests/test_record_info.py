"""``polartrack info``: the figures of a recording built here, a cut one, and files that are not MCAP."""

from __future__ import annotations

import json

import pytest
from mcap.writer import CompressionType, Writer

from common.record.info import InfoError, format_info, recording_info
from services.cli import main

T0 = 1_700_000_000_000_000_000  # ns


def write(path, compression=CompressionType.ZSTD, chunk_size=4096, finish=True):
    """10 s of 'frame/info' at 10 Hz (101 messages, t = 0..10 s) and 'status/x' at 1 Hz (11), with run metadata."""
    fh = open(path, "wb")
    w = Writer(fh, compression=compression, chunk_size=chunk_size)
    w.start(profile="protobuf", library="test-writer")
    s1 = w.register_schema("polartrack.FrameInfo", "protobuf", b"fake")
    s2 = w.register_schema("polartrack.ServiceStatus", "protobuf", b"fake")
    info = w.register_channel("frame/info", "protobuf", s1)
    status = w.register_channel("status/x", "protobuf", s2)
    w.add_metadata("run", {"run_id": "r1", "source": "synthetic:3", "init_box": "[1, 2, 3, 4]",
                           "settings_json": json.dumps({"seed": 7, "filter": "rbpf"})})
    for i in range(101):
        t = T0 + i * 100_000_000
        w.add_message(info, log_time=t, publish_time=t, data=bytes([i % 256]) * 200)
        if i % 10 == 0:
            w.add_message(status, log_time=t, publish_time=t, data=b"ok")
    if finish:
        w.finish()
    fh.close()


def test_info_of_a_recording_built_here(tmp_path):
    path = tmp_path / "r.mcap"
    write(path)
    info = recording_info(str(path))
    assert info.complete and info.messages == 112
    assert info.start_ns == T0 and info.end_ns == T0 + 10_000_000_000 and info.duration_s == pytest.approx(10.0)
    topics = {t.topic: t for t in info.topics}
    assert topics["frame/info"].messages == 101 and topics["frame/info"].rate_hz == pytest.approx(10.1)
    assert topics["status/x"].messages == 11 and topics["status/x"].schema == "polartrack.ServiceStatus"
    assert info.compression == ["zstd"] and info.chunks >= 5
    assert info.uncompressed_bytes > info.compressed_bytes  # repeated bytes compress
    assert info.size_bytes == path.stat().st_size and info.library == "test-writer"
    assert info.run == {"run_id": "r1", "source": "synthetic:3", "init_box": "[1, 2, 3, 4]", "seed": 7, "filter": "rbpf"}
    text = format_info(info)
    assert "Duration:          10.000 s" in text and "frame/info" in text and "10.10 Hz" in text and "seed 7" in text


def test_uncompressed_chunks_are_reported_as_none(tmp_path):
    path = tmp_path / "r.mcap"
    write(path, compression=CompressionType.NONE)
    info = recording_info(str(path))
    assert info.compression == [""] and info.compressed_bytes == info.uncompressed_bytes
    assert "none:" in format_info(info)


def test_a_cut_recording_is_counted_up_to_the_cut(tmp_path):
    whole = tmp_path / "whole.mcap"
    write(whole, chunk_size=2048)
    data = whole.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    info = recording_info(str(cut))
    assert not info.complete
    full = recording_info(str(whole))
    assert 0 < info.messages < full.messages  # the complete chunks before the cut, no more
    assert info.start_ns == T0 and info.end_ns < full.end_ns
    assert info.run["seed"] == 7  # the metadata is written first
    assert "cut short" in format_info(info)


def test_not_an_mcap_file(tmp_path, capsys):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"garbage" * 10)
    with pytest.raises(InfoError, match="not a readable MCAP file"):
        recording_info(str(bad))
    assert main(["info", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not a readable MCAP file" in err
    assert main(["info", str(tmp_path / "missing.mcap")]) == 2
    assert "No such file" in capsys.readouterr().err


def test_info_json(tmp_path, capsys):
    path = tmp_path / "r.mcap"
    write(path)
    assert main(["info", str(path), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["messages"] == 112 and d["duration_s"] == 10.0 and d["run"]["seed"] == 7
    assert {t["topic"]: t["messages"] for t in d["topics"]} == {"frame/info": 101, "status/x": 11}
    assert d["metadata"]["run"]["source"] == "synthetic:3"


def test_a_cut_file_with_a_corrupted_chunk_stops_there(tmp_path):
    whole = tmp_path / "whole.mcap"
    write(whole, chunk_size=2048)
    data = bytearray(whole.read_bytes())
    full = recording_info(str(whole))
    cut = data[: len(data) * 3 // 4]
    mid = len(cut) // 2
    cut[mid: mid + 64] = b"\xff" * 64  # garbage inside a compressed chunk
    path = tmp_path / "bad.mcap"
    path.write_bytes(bytes(cut))
    info = recording_info(str(path))
    assert not info.complete and 0 < info.messages < full.messages
