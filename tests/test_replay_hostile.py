"""``replay`` of hostile and cut recordings: streamed with bounded memory, a bad record counted
and skipped, a bad file or garbled run settings one line (exit 2), never a traceback.

The recording is made in-process (no bus): the Tracker's queries answered by the detector
service's core, every message written by the recorder's MCAP sink as a run would; crafted
variants are written with the mcap writer (garbage in one estimate, info, reply, the run's
settings or init box), at byte level (a chunk's bytes flipped, a zstd bomb chunk, a cut file).
"""

from __future__ import annotations

import json
import struct
import tracemalloc

import pytest
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.records import Chunk

from common.detector.remote import QueryDetector
from common.msgs import FrameInfo, RunConfig, ScoreQuery
from common.msgs.convert import estimate_msg, info_frame, msg_to_template, template_to_msg
from common.msgs.image_wire import encode_image
from common.record.reader import MAX_CHUNK_BYTES, RecordingError, read_recording, run_metadata, stream_messages
from common.record.retrack import offline_retrack
from common.single_target.runner import Tracker
from common.sources import open_source
from parity import parity_settings, rewrite_mcap
from services.cli import main
from common.detector.server import DetectorCore
from common.record.writer import McapSink

SOURCE = "synthetic:3"
FRAMES = 12
GARBAGE = b"\xff\x01\x99garbage\x00\x13\x37" * 5


def info_of(f, ns: int) -> FrameInfo:
    info = FrameInfo(index=f.index, time_s=f.time, capture_ns=ns, width=f.size[0], height=f.size[1],
                     source=SOURCE, total_frames=FRAMES)
    if f.homography is not None:
        info.homography.extend(f.homography.ravel())
    return info


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    """A single-target recording of FRAMES frames as the recorder writes it (stabilised: the
    frames' images are read on offline replay)."""
    path = tmp_path_factory.mktemp("replay") / "clean.mcap"
    src = open_source(SOURCE, n_frames=FRAMES)
    frames = list(src)
    st = parity_settings(src)
    box = frames[0].truth.box
    core = DetectorCore()
    sink = McapSink(str(path), "lz4", 64 << 10)
    now = [0]

    def ask(q):
        sink.write("detector/query", q.SerializeToString(), now[0], now[0])
        rep = core.handle(ScoreQuery.FromString(q.SerializeToString()))[0]
        sink.write("detector/reply", rep.SerializeToString(), now[0], now[0])
        return rep

    def publish(template, version):
        core.install_template(version, msg_to_template(template_to_msg(template, version, 0)))

    rc = RunConfig(run_id="t", source=SOURCE, init_box=list(box), settings_json=st.model_dump_json(), seed=3,
                   pace="consumer", start_ns=10**9)
    sink.write("run/config", rc.SerializeToString(), 10**9, 10**9)
    sink.metadata("run", run_metadata(rc.SerializeToString()))
    tracker = None
    for f in frames:
        ns = now[0] = 10**9 + f.index * 33_333_333
        info = info_of(f, ns)
        sink.write("frame/image", encode_image(f.image, ns, f.index), ns, ns)
        sink.write("frame/info", info.SerializeToString(), ns, ns)
        core.add_frame(f.index, f.image, f.time)
        rf = info_frame(info, f.image)
        tracker = tracker or Tracker.start(rf, box, st, QueryDetector(ask, "t", publish))
        sink.write("track/estimate", estimate_msg(f.index, ns, tracker.step(rf), st.filter).SerializeToString(), ns, ns)
    sink.write("frame/info", FrameInfo(index=FRAMES, end_of_stream=True, capture_ns=now[0]).SerializeToString(),
               now[0], now[0])
    sink.close()
    return path


def replay_cli(capsys, *args):
    code = main(["replay", *map(str, args)])
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    return code, out, err


def garble_nth(topic: str, n: int):
    """An edit for rewrite_mcap: the n-th message of ``topic`` (0-based) replaced by garbage."""
    seen = {}

    def edit(t, data):
        k = seen[t] = seen.get(t, -1) + 1
        return GARBAGE if t == topic and k == n else data

    return edit


def test_clean_recording_replays_identical_offline(clean, capsys):
    out = offline_retrack(str(clean))
    assert out["identical"] and out["compared"] == out["recorded"] == FRAMES
    assert out["query_mismatch"] == 0 and out["malformed"] == {}
    code, stdout, _ = replay_cli(capsys, clean, "--offline")
    assert code == 0 and f"{FRAMES} estimates compared with {FRAMES} recorded: identical" in stdout


@pytest.mark.parametrize("topic, n", [("track/estimate", 5), ("frame/info", 5), ("detector/reply", 7)])
def test_garbage_message_is_counted_and_skipped(clean, tmp_path, capsys, topic, n):
    bad = tmp_path / "bad.mcap"
    rewrite_mcap(clean, bad, garble_nth(topic, n))
    out = offline_retrack(str(bad))
    assert out["malformed"] == {topic: 1}
    if topic == "track/estimate":  # the frame without its estimate is not stepped on, as live
        assert out["recorded"] == FRAMES - 1
    if topic == "frame/info":
        assert out["compared"] == FRAMES - 1 and 5 in out["missing"]
    code, stdout, _ = replay_cli(capsys, bad, "--offline")
    assert code in (0, 1) and f"malformed messages skipped: {topic} 1" in stdout


@pytest.mark.parametrize("key, value, said", [
    ("settings_json", '{"filter": "rbpf", "particles": "many"', "settings are not valid tracker settings"),
    ("settings_json", json.dumps({"particles": -5}), "settings are not valid tracker settings"),
    ("init_box", "[1, 2, garbage", "init box is not x,y,w,h"),
    ("init_box", "[1, 2, 3]", "init box is not x,y,w,h"),
])
def test_garbled_run_settings_are_one_line(clean, tmp_path, capsys, key, value, said):
    from mcap.reader import make_reader
    from mcap.writer import Writer

    bad = tmp_path / "bad.mcap"
    with open(clean, "rb") as fh, open(bad, "wb") as out:  # the same messages, the run metadata garbled
        reader = make_reader(fh)
        w = Writer(out)
        w.start()
        for m in reader.iter_metadata():
            w.add_metadata(m.name, {**m.metadata, key: value} if m.name == "run" else dict(m.metadata))
        ids = {}
        for schema, ch, msg in reader.iter_messages(log_time_order=False):
            sid = ids.get(("s", schema.id)) or ids.setdefault(("s", schema.id), w.register_schema(
                schema.name, schema.encoding, schema.data))
            cid = ids.get(ch.id) or ids.setdefault(ch.id, w.register_channel(ch.topic, ch.message_encoding, sid))
            w.add_message(cid, msg.log_time, msg.data, msg.publish_time, msg.sequence)
        w.finish()
    with pytest.raises(RecordingError, match=said):
        offline_retrack(str(bad))
    for mode in ("--offline", "--retrack"):  # retrack checks before starting any service
        code, _, err = replay_cli(capsys, bad, mode)
        assert code == 2 and said in err and err.count("\n") == 1, err


def records(*recs) -> bytes:
    b = RecordBuilder()
    for r in recs:
        r.write(b)
    return b.end()


def insert_before_footer(path, dst, blob: bytes) -> None:
    """``path``'s records with ``blob`` (whole records) inserted before its data end record."""
    data = path.read_bytes()
    # the data section ends with the DataEnd record (opcode 0x0F, length 4): find its start
    at = data.rfind(b"\x0f" + struct.pack("<Q", 4))
    assert at > 0
    dst.write_bytes(data[:at] + blob + data[at:])


def zstd_bomb(size: int) -> bytes:
    """``size`` zero bytes, zstd-compressed in pieces (never all in memory)."""
    c = zstandard.ZstdCompressor(level=3).compressobj()
    piece = bytes(1 << 20)
    out = [c.compress(piece) for _ in range(size >> 20)]
    return b"".join(out) + c.flush()


@pytest.mark.parametrize("stated", ["true", "understated"])
def test_zstd_bomb_chunk_is_skipped_with_bounded_memory(clean, tmp_path, capsys, stated):
    size = 1 << 30
    bomb = zstd_bomb(size)
    assert len(bomb) < 1 << 20  # 1 GiB of zeros in well under 1 MiB
    chunk = Chunk(compression="zstd", data=bomb, message_start_time=0, message_end_time=0,
                  uncompressed_size=size if stated == "true" else 1 << 20, uncompressed_crc=0)
    bad = tmp_path / "bomb.mcap"
    insert_before_footer(clean, bad, records(chunk))
    tracemalloc.start()
    try:
        rec = read_recording(str(bad), warn=lambda m: None, skip=("frame/image",))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    reason = "chunk_too_large" if stated == "true" else "chunk_size_mismatch"
    assert rec.report.skipped == {reason: 1}
    assert rec.counts["track/estimate"] == FRAMES  # everything else read
    assert peak < 16 << 20  # a frame's chunk at a time, not the bomb's gigabyte
    assert MAX_CHUNK_BYTES < size
    code, stdout, err = replay_cli(capsys, bad, "--offline")
    assert code == 0 and "identical" in stdout and f"records skipped: {reason} 1" in err


def test_flipped_bytes_in_a_chunk_fail_its_crc_and_are_skipped(clean, tmp_path, capsys):
    data = bytearray(clean.read_bytes())
    at = data.find(b"track/estimate")  # a channel record; the chunks after hold the frames
    mid = len(data) // 2
    data[mid:mid + 64] = bytes(64)
    assert at > 0
    bad = tmp_path / "flipped.mcap"
    bad.write_bytes(bytes(data))
    rec = read_recording(str(bad), warn=lambda m: None)
    assert sum(rec.report.skipped.values()) >= 1
    assert set(rec.report.skipped) <= {"chunk_crc", "chunk_not_decompressible", "chunk_size_mismatch", "bad_chunk"}
    good = read_recording(str(clean))
    assert 0 < sum(rec.counts.values()) < sum(good.counts.values())
    code, _, err = replay_cli(capsys, bad, "--offline")
    assert code in (0, 1, 2) and "records skipped" in err


def test_not_an_mcap_file_is_one_line(tmp_path, capsys):
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(GARBAGE * 100)
    for mode in ("--offline", "--retrack", "--max"):
        code, _, err = replay_cli(capsys, junk, mode)
        assert code == 2 and "not an MCAP file" in err and err.count("\n") == 1, err
    code, _, err = replay_cli(capsys, tmp_path / "missing.mcap", "--offline")
    assert code == 2 and "no such file" in err


def test_a_huge_record_length_is_a_cut_not_an_allocation(clean, tmp_path):
    data = clean.read_bytes()
    bad = tmp_path / "huge.mcap"
    at = data.rfind(b"\x0f" + struct.pack("<Q", 4))
    bad.write_bytes(data[:at] + b"\x05" + struct.pack("<Q", 1 << 62) + b"xx")
    tracemalloc.start()
    try:
        rec = read_recording(str(bad), warn=lambda m: None, skip=("frame/image",))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert "past the end of the file" in rec.report.cut and rec.counts["track/estimate"] == FRAMES
    assert peak < 16 << 20


def test_streaming_holds_one_chunk_not_the_file(clean):
    """The frame images (most of the file) are streamed: reading every message holds a chunk at a
    time, and the replay's read of the other topics holds only them."""
    size = clean.stat().st_size
    assert size > 30 << 20
    tracemalloc.start()
    try:
        n = sum(1 for _ in stream_messages(str(clean)))
        stream_peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.reset_peak()
        rec = read_recording(str(clean), skip=("frame/image",))
        small_peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert n == sum(rec.counts.values()) and rec.counts["frame/image"] == FRAMES and "frame/image" not in rec.messages
    # a few copies of one chunk (a 2.8 MB frame: read, decompressed, the message), not the 33 MB file
    assert stream_peak < 16 << 20 and small_peak < 16 << 20, (stream_peak, small_peak, size)


def cut(clean, dst, fraction: float) -> None:
    data = clean.read_bytes()
    dst.write_bytes(data[:int(len(data) * fraction)])


def test_cut_recording_replays_offline_up_to_the_cut(clean, tmp_path, capsys):
    bad = tmp_path / "cut.mcap"
    cut(clean, bad, 0.6)
    out = offline_retrack(str(bad))
    assert out["identical"] and 0 < out["compared"] == out["recorded"] < FRAMES
    capsys.readouterr()
    code, stdout, err = replay_cli(capsys, bad, "--offline")
    assert code == 0 and "identical" in stdout and "cut short" in err and err.count("\n") == 1


def test_cut_recording_republishes_up_to_the_cut(clean, tmp_path, capsys):
    bad = tmp_path / "cut.mcap"
    cut(clean, bad, 0.6)
    readable = sum(read_recording(str(bad), warn=lambda m: None).counts.values())
    code, stdout, err = replay_cli(capsys, bad, "--max", "--json")
    out = json.loads(stdout)
    assert code == 0 and out["messages"] == readable > 0
    assert "past the end of the file" in out["cut"] or "without a footer" in out["cut"]
    assert "cut short" in err


def test_cut_recording_retracks_up_to_the_cut(clean, tmp_path, capsys):
    """The live detector and tracker re-run on the frames up to the cut: identical."""
    bad = tmp_path / "cut.mcap"
    cut(clean, bad, 0.6)
    code, stdout, err = replay_cli(capsys, bad, "--retrack", "--json")
    out = json.loads(stdout)
    assert code == 0 and out["identical"] and 0 < out["compared"] == out["recorded"] < FRAMES, out
    assert "cut short" in err
