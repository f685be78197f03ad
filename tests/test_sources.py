"""Frame sources: formats, ground truth conventions, and clear errors for bad input."""

import cv2
import numpy as np
import pytest

from common.sources import FolderSource, SourceError, VideoSource, open_source, read_groundtruth


def _make_folder(tmp_path, n_frames=3, n_boxes=3, name="seq", lines=None):
    d = tmp_path / name
    (d / "img").mkdir(parents=True)
    for i in range(n_frames):
        img = np.full((40, 60, 3), i * 20, np.uint8)
        img[10, 20] = (255, 0, 0)  # a red pixel (RGB) to check channel order
        cv2.imwrite(str(d / "img" / f"{i + 1:06d}.png"), img[:, :, ::-1])  # lossless: exact colours
    if lines is None:
        lines = [f"{5 + i},{6 + i},10,8" for i in range(n_boxes)]
    (d / "groundtruth_rect.txt").write_text("\n".join(lines) + "\n")
    return d


def test_folder_source_reads_frames_and_truth(tmp_path):
    d = _make_folder(tmp_path, lines=["5,6,10,8", "NaN,NaN,NaN,NaN", "7\t8\t10\t8"])
    src = open_source(str(d))
    assert isinstance(src, FolderSource) and len(src) == 3 and src.has_truth
    frames = list(src)
    assert [f.index for f in frames] == [0, 1, 2]
    assert frames[1].time == pytest.approx(1 / 30)
    assert frames[0].truth.box == (5.0, 6.0, 10.0, 8.0) and frames[0].truth.centre == (10.0, 10.0)
    assert frames[1].truth.box is None  # NaN line: not visible
    assert frames[2].truth.box == (7.0, 8.0, 10.0, 8.0)
    r, g, b = frames[0].image[10, 20]
    assert r > 200 and g < 60 and b < 60  # RGB order


def test_frames_limit_applies_to_folders(tmp_path):
    """``--frames N`` (open_source's n_frames) keeps the first N frames of a folder too."""
    d = _make_folder(tmp_path, lines=["5,6,10,8", "NaN,NaN,NaN,NaN", "7\t8\t10\t8"])
    src = open_source(str(d), n_frames=2)
    assert len(src) == 2 and [f.index for f in src] == [0, 1] and src.frame(1).truth.box is None


def test_uav123_boxes_count_from_one(tmp_path):
    d = _make_folder(tmp_path, name="uav123-test", lines=["5,6,10,8"] * 3)
    assert open_source(str(d)).frame(0).truth.box == (4.0, 5.0, 10.0, 8.0)


def test_folder_with_mismatched_truth_count(tmp_path):
    d = _make_folder(tmp_path, n_frames=3, n_boxes=5)
    with pytest.raises(SourceError, match="5 boxes but img/ has 3 frames"):
        open_source(str(d))


def test_bad_groundtruth_line(tmp_path):
    p = tmp_path / "gt.txt"
    p.write_text("1,2,3,4\n1,2,x,4\n")
    with pytest.raises(SourceError, match=r"gt.txt:2: expected x,y,w,h"):
        read_groundtruth(p)
    p.write_text("1,2,3\n")
    with pytest.raises(SourceError, match="expected 4 values"):
        read_groundtruth(p)


def test_empty_folder_and_missing_path(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(SourceError, match="no images found"):
        open_source(str(tmp_path / "empty"))
    with pytest.raises(SourceError, match="no such file or folder"):
        open_source(str(tmp_path / "nothing.mp4"))


def test_a_frame_of_another_size_in_a_folder_is_a_source_error(tmp_path):
    """A folder whose frames change size mid-sequence (the tracker's optical flow raised on it)
    gives a SourceError naming the frame and both sizes; the frames before it are read."""
    d = tmp_path / "seq" / "img"
    d.mkdir(parents=True)
    for i, (w, h) in enumerate([(64, 48), (64, 48), (80, 40), (64, 48)]):
        cv2.imwrite(str(d / f"{i + 1:04d}.jpg"), np.full((h, w, 3), 30 * i, np.uint8))
    src = open_source(str(tmp_path / "seq"))
    frames = iter(src)
    assert [next(frames).size for _ in range(2)] == [(64, 48), (64, 48)]
    with pytest.raises(SourceError, match=r"0003.jpg: 80x40 pixels, the folder's other frames 64x48"):
        next(frames)
    assert src.frame(3).size == (64, 48)  # the control: a frame of the folder's size


def test_unreadable_video(tmp_path):
    p = tmp_path / "broken.mp4"
    p.write_bytes(b"\x00\x01 definitely not a video" * 100)
    with pytest.raises(SourceError, match="not a readable video"):
        open_source(str(p))


def test_video_source_round_trip(tmp_path):
    p = tmp_path / "clip.avi"
    w = cv2.VideoWriter(str(p), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (64, 48))
    assert w.isOpened()
    for i in range(5):
        w.write(np.full((48, 64, 3), 40 * i, np.uint8))
    w.release()
    src = open_source(str(p))
    assert isinstance(src, VideoSource) and src.fps == pytest.approx(25.0)
    frames = list(src)
    assert len(frames) == 5 and frames[3].time == pytest.approx(3 / 25)
    assert abs(int(frames[3].image.mean()) - 120) <= 3
    short = open_source(str(p), n_frames=3)
    assert len(short) == 3 and len(list(short)) == 3


def test_synthetic_specs():
    src = open_source("synthetic:3", n_frames=5)
    assert len(src) == 5 and src.name == "synthetic-3" and src.has_truth
    f = src.frame(2)
    assert f.homography.shape == (3, 3) and f.truth.angle_deg is not None
    with pytest.raises(SourceError, match="synthetic:SEED"):
        open_source("synthetic:abc")


def test_prerendered_source_holds_the_same_frames():
    from common.sources import PrerenderedSource

    live = open_source("synthetic:2", n_frames=6)
    pre = PrerenderedSource(open_source("synthetic:2", n_frames=6))
    assert len(pre) == 6 and pre.fps == live.fps and pre.has_truth
    for i in (0, 3, 5):
        a, b = live.frame(i), pre.frame(i)
        assert np.array_equal(a.image, b.image) and np.array_equal(a.homography, b.homography)
        assert a.truth == b.truth and pre.true_centre(i) == live.true_centre(i)
    assert [f.index for f in pre] == list(range(6))


def test_prerendering_refuses_what_it_cannot_hold():
    from common.sources import PrerenderedSource, SourceError

    with pytest.raises(SourceError, match="GiB"):
        PrerenderedSource(open_source("synthetic:2", n_frames=6), max_bytes=1 << 20)


def test_realtime_clock_restart_drops_nothing():
    """The ingest's real-time clock, restarted after a pause (the tracker setting up on frame 0),
    publishes the next frames on time instead of counting the pause as frames to skip."""
    import time

    from services.bus import Counters
    from services.ingest import Clock, frames_to_publish

    src = open_source("synthetic:1", n_frames=30)

    def run(restart: bool) -> tuple[list[int], int]:
        clock, counters = Clock(), Counters("test")
        seen = []
        for frame in frames_to_publish(src, "realtime", counters, clock):
            seen.append(frame.index)
            if frame.index == 1:
                time.sleep(0.5)  # fifteen frames' time
                if restart:
                    clock.start(frame.time)
            if len(seen) == 3:
                break
        return seen, counters["dropped"]

    seen, dropped = run(restart=True)
    assert seen[:2] == [0, 1] and dropped <= 1  # (a frame if rendering the next took over 33 ms)
    seen, dropped = run(restart=False)  # negative control: the pause counted as late frames
    assert seen[2] >= 12 and dropped >= 10


def test_realtime_late_frames_within_max_late_are_published_not_dropped():
    """A reader held up for 2 frame periods publishes the late frames (a camera's buffer) with
    ``max_late=4``, and skips them with ``max_late=0`` (the negative control). The clock knows how
    late each frame is, which the ingest subtracts from its capture stamp. The frames are rendered
    before (the renderer's ~20 ms a frame on a loaded machine would add to the lateness), and the
    margin is two frame periods, so a busy machine's scheduling does not decide the outcome."""
    import time

    from common.sources import PrerenderedSource
    from services.bus import Counters
    from services.ingest import Clock, frames_to_publish

    src = PrerenderedSource(open_source("synthetic:1", n_frames=12))

    def run(max_late: int) -> tuple[list[int], int, float]:
        clock, counters = Clock(), Counters("test")
        seen, late = [], 0.0
        for frame in frames_to_publish(src, "realtime", counters, clock, max_late=max_late):
            seen.append(frame.index)
            time.sleep(max(0.0, clock.wall0 + frame.time - time.monotonic()))  # on time, as the ingest
            if frame.index == 2:
                time.sleep(2.0 / src.fps)
            if frame.index == 3:
                late = clock.lateness_s(frame.time)
            if len(seen) == 4:
                break
        return seen, counters["dropped"], late

    seen, dropped, late = run(4)
    assert seen == [0, 1, 2, 3] and dropped == 0 and late > 1.0 / src.fps
    seen, dropped, _ = run(0)
    assert seen[3] >= 4 and dropped >= 1


def test_clock_reset_makes_the_next_frame_due_when_read():
    import time

    from services.bus import Counters
    from services.ingest import Clock, frames_to_publish

    src = open_source("synthetic:1", n_frames=12)
    for reset, expect_drop in ((True, False), (False, True)):
        clock, counters = Clock(), Counters("test")
        seen = []
        for frame in frames_to_publish(src, "realtime", counters, clock):
            seen.append(frame.index)
            if frame.index == 0:
                time.sleep(0.2)  # the set-up on frame 0: six frame periods
                if reset:
                    clock.reset()
            if len(seen) == 2:
                break
        assert (seen[1] != 1) == expect_drop, (reset, seen)
        assert (counters["dropped"] > 0) == expect_drop
    assert Clock().lateness_s(5.0) == 0.0  # not started: never late


def test_pause_holds_the_source_until_resumed_and_a_stop_ends_the_hold():
    """SIGUSR1 holds ingest before its next frame, SIGUSR2 lets it go (what
    ``Pipeline.pause_source`` sends instead of SIGSTOP); a stop ends a hold at once."""
    import os
    import signal
    import threading
    import time

    from services.bus import Stopper
    from services.ingest import Pause

    saved = {s: signal.getsignal(s) for s in (signal.SIGUSR1, signal.SIGUSR2, signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    try:
        pause, stopper = Pause(), Stopper()
        assert pause.wait(stopper) == 0.0  # not held: no wait at all
        os.kill(os.getpid(), signal.SIGUSR1)
        assert pause.held.is_set()
        threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGUSR2)).start()
        t0 = time.monotonic()
        held = pause.wait(stopper)
        assert 0.25 <= held and time.monotonic() - t0 >= 0.25 and not pause.held.is_set()
        os.kill(os.getpid(), signal.SIGUSR1)
        threading.Timer(0.1, stopper.event.set).start()
        assert pause.wait(stopper) < 5 and pause.held.is_set()  # stopped while held: back at once
    finally:
        for s, h in saved.items():
            signal.signal(s, h)


def test_breakpoint_holds_until_a_resume_whenever_it_came():
    """``pause_before``'s hold ends at the first SIGUSR2, whether it comes while the source is
    held there or came before the source got there (a launcher can hear of the frame before
    and resume first); without any, only a stop ends it."""
    import os
    import signal
    import threading
    import time

    from services.bus import Stopper
    from services.ingest import Pause

    saved = {s: signal.getsignal(s) for s in (signal.SIGUSR1, signal.SIGUSR2, signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    try:
        pause, stopper = Pause(), Stopper()
        threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGUSR2)).start()
        t0 = time.monotonic()
        held = pause.breakpoint(stopper)
        assert 0.25 <= held and time.monotonic() - t0 >= 0.25 and pause.resumes == 1

        early = Pause()
        os.kill(os.getpid(), signal.SIGUSR2)  # the resume first
        assert early.breakpoint(stopper) < 0.05  # then the breakpoint: not held

        never, stop = Pause(), Stopper()  # negative control: no resume, only the stop ends it
        threading.Timer(0.3, stop.event.set).start()
        t0 = time.monotonic()
        assert never.breakpoint(stop) >= 0.25 and never.resumes == 0 and time.monotonic() - t0 < 5
    finally:
        for s, h in saved.items():
            signal.signal(s, h)
