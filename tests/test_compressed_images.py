"""Compressed frames on the bus and in the recording (foxglove.CompressedImage), still exact: a
folder of JPEGs goes out as its files' own bytes, a video's frames as JPEG (lossy: every consumer
decodes the published bytes, and ``track`` decodes the same); live run == in-process track ==
offline replay == retrack bit for bit, for both sources. The sources are made here from the
synthetic scene's frames (a folder of JPEG files with their ground truth, an MP4 file)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from mcap.reader import make_reader

from common.msgs.convert import estimate_msg
from common.msgs.image_wire import CAMERA_FRAME, decode_frame
from common.record.retrack import offline_retrack, same_estimate
from common.record.reader import read_recording
from common.single_target.runner import track_frames
from common.settings import profile_for
from common.sources import open_source
from common.sources.published import PublishedSource, as_published, parse_image_format
from services.launcher import Pipeline

pytestmark = pytest.mark.slow  # services as separate processes on a loopback bus

FRAMES = 10


@pytest.fixture(scope="module")
def sources(tmp_path_factory):
    root = tmp_path_factory.mktemp("compressed")
    frames = list(open_source("synthetic:3", n_frames=FRAMES))
    folder = root / "seq"
    (folder / "img").mkdir(parents=True)
    for f in frames:
        cv2.imwrite(str(folder / "img" / f"{f.index + 1:06d}.jpg"), f.image[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 90])
    (folder / "groundtruth_rect.txt").write_text("".join(",".join(f"{v:.2f}" for v in f.truth.box) + "\n" for f in frames))
    video = root / "clip.mp4"
    h, w = frames[0].image.shape[:2]
    out = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, (w, h))
    for f in frames:
        out.write(np.ascontiguousarray(f.image[:, :, ::-1]))
    out.release()
    return {"folder": str(folder), "video": str(video), "box": frames[0].truth.box}


def run_and_track(spec, box, tmp):
    src = open_source(spec, n_frames=FRAMES)
    settings = profile_for(src, seed=3)
    with Pipeline(spec, box, settings, out_dir=tmp, frames=FRAMES, viewer=False, log_dir=tmp) as pipe:
        result = pipe.run(progress=False, timeout=300)
    assert result.ok and result.estimates == FRAMES, result
    expected = [estimate_msg(f.index, 0, s, settings.filter)
                for f, s in track_frames(PublishedSource(src, "auto"), box, settings)]
    return result, expected


def recorded_images(path):
    with open(path, "rb") as fh:
        return [(schema.name, msg.data) for schema, _ch, msg in make_reader(fh).iter_messages(topics=["frame/image"])]


@pytest.mark.parametrize("kind", ["folder", "video"])
def test_compressed_run_equals_track_and_replay_bit_for_bit(sources, kind, tmp_path):
    result, expected = run_and_track(sources[kind], sources["box"], tmp_path)
    rec = read_recording(result.mcap)
    got = sorted(rec.decoded("track/estimate"), key=lambda e: e.frame_index)
    assert [e.frame_index for e in got] == list(range(FRAMES))
    assert [e.frame_index for e, x in zip(got, expected) if not same_estimate(e, x)] == []
    images = recorded_images(result.mcap)
    assert {name for name, _ in images} == {"foxglove.CompressedImage"} and len(images) == FRAMES
    decoded = [decode_frame(data) for _, data in images]
    assert [i for i, _, _ in decoded] == list(range(FRAMES)) and {m.frame_id for _, m, _ in decoded} == {CAMERA_FRAME}
    src = open_source(sources[kind], n_frames=FRAMES)
    for (index, msg, pixels), frame in zip(decoded, src):
        assert msg.format == "jpeg"
        if kind == "folder":  # the file's own bytes, untouched
            assert bytes(msg.data or b"") == b"" and frame.encoded[1] in images[index][1]
        assert np.array_equal(pixels, as_published(frame, "auto", src.image_format).image)
    out = offline_retrack(result.mcap)
    assert out["identical"] and out["compared"] == FRAMES, out
    from services.replay import retrack

    out = retrack(result.mcap, timeout=240)  # the recorded bytes fed to a fresh detector and tracker
    assert out["identical"] and out["compared"] == FRAMES, out


def test_the_video_frames_are_lossy_and_the_comparison_sees_it(sources):
    """Negative control: the video's raw frames differ from what the bus carries (so the equality
    above needed ``track`` to decode the same JPEG)."""
    src = open_source(sources["video"], n_frames=2)
    frame = next(iter(src))
    assert src.image_format == "jpeg:90"
    assert not np.array_equal(frame.image, as_published(frame, "auto", src.image_format).image)
    assert np.array_equal(frame.image, as_published(frame, "png", src.image_format).image)  # lossless


@pytest.mark.parametrize("spec, ok", [("auto", True), ("jpeg:80", True), ("png", True), ("raw", True),
                                      ("jpeg:0", False), ("png:3", False), ("gif", False)])
def test_image_format_names(spec, ok):
    if ok:
        parse_image_format(spec)
    else:
        with pytest.raises(ValueError):
            parse_image_format(spec)
