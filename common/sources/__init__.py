"""Frame sources: a video file, a UAV123-format folder, an image-sequence folder, a camera, or
the built-in synthetic scene, all yielding :class:`Frame` in source order.

Source strings (the ``SOURCE`` argument of the commands):

- ``synthetic``, ``synthetic:SEED`` or ``synthetic:SEED:LENGTH``: the built-in scene
  (:mod:`common.scene`), 300 frames unless LENGTH says otherwise (its events keep their
  places as fractions of the run);
- a folder with ``img/*.jpg`` and ``groundtruth_rect.txt`` (UAV123/OTB format, ``x,y,w,h`` per
  line, ``NaN`` where the target is not visible); a folder of images without ground truth;
- a video file readable by OpenCV;
- ``camera:N``: live camera device N (real-time: frames are timestamped on capture);
- ``people``, ``people:SEED`` or ``people:SEED:PEOPLE``: the synthetic people scene
  (:mod:`common.scene.people`, 3 people unless PEOPLE says otherwise) with per-part ground truth
  (``people_truth(i)``); ``n_frames`` (at least 10) sets the scene's length, as ``track-multi``;
- ``zoom[:SEED]``, ``exit[:SEED[:FPS]]``: the synthetic event sequences of :mod:`common.scene.events`
  (a 10x zoom onto the car; the car leaving the frame and coming back elsewhere, at 10 fps unless
  FPS says otherwise: the same events in seconds), tracked with the real-footage profile (no
  homography).
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from common.sources.base import IMAGE_SUFFIXES, Frame, GroundTruth, Source, SourceError, WrappedSource

__all__ = ["IMAGE_SUFFIXES", "Frame", "GroundTruth", "Source", "SourceError", "open_source"]


class SyntheticSource(Source):
    def __init__(self, seed: int = 0, n_frames: int | None = None, config=None):
        """``n_frames`` keeps only the first frames of the scene (whose timeline is unchanged)."""
        from common.scene import SceneConfig, SyntheticScene

        self.scene = SyntheticScene(config if config is not None else SceneConfig(), seed=seed)
        self.limit = len(self.scene) if n_frames is None else max(0, min(int(n_frames), len(self.scene)))
        self.seed = seed
        self.name = f"synthetic-{seed}"
        self.fps = float(self.scene.fps)

    def __len__(self) -> int:
        return self.limit

    @property
    def has_truth(self) -> bool:
        return True

    def frame(self, i: int) -> Frame:
        f = self.scene.frame(i)
        t = f.truth
        truth = GroundTruth(box=tuple(float(v) for v in t.box) if t.visible_fraction > 0 else None,
                            angle_deg=float(t.angle_image_deg), visible_fraction=float(t.visible_fraction))
        return Frame(index=i, time=float(f.time), image=f.image, homography=np.asarray(f.homography, float),
                     truth=truth)

    def true_centre(self, i: int) -> tuple[float, float]:
        """Target centre even while hidden (the scene knows it)."""
        x, y = self.scene.truth(i).image_xy  # no rendering
        return (float(x), float(y))

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self)):
            yield self.frame(i)


def read_groundtruth(path: Path) -> list[tuple[float, float, float, float] | None]:
    """Parse ``groundtruth_rect.txt``: ``x,y,w,h`` per line (commas, tabs or spaces)."""
    boxes: list[tuple[float, float, float, float] | None] = []
    for n, line in enumerate(path.read_text().splitlines(), start=1):
        line = line.strip()
        if not line:
            continue
        parts = line.replace("\t", ",").replace(" ", ",").split(",")
        parts = [p for p in parts if p]
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            raise SourceError(f"{path}:{n}: expected x,y,w,h numbers, got {line!r}") from None
        if len(vals) != 4:
            raise SourceError(f"{path}:{n}: expected 4 values x,y,w,h, got {len(vals)}")
        if any(math.isnan(v) for v in vals):
            boxes.append(None)
        else:
            boxes.append((vals[0], vals[1], vals[2], vals[3]))
    return boxes


class FolderSource(Source):
    """A folder of frames (``img/`` sub-folder or the folder itself), optional ground truth."""

    def __init__(self, folder: Path, fps: float = 30.0, one_based_truth: bool | None = None,
                 n_frames: int | None = None):
        """``n_frames`` keeps only the first frames."""
        folder = Path(folder)
        img_dir = folder / "img" if (folder / "img").is_dir() else folder
        self.files = sorted(p for p in img_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not self.files:
            raise SourceError(f"{folder}: no images found (expected img/*.jpg or image files in the folder)")
        self.name = folder.name
        self.fps = fps
        gt_path = folder / "groundtruth_rect.txt"
        self.truth: list | None = None
        if gt_path.exists():
            boxes = read_groundtruth(gt_path)
            if len(boxes) != len(self.files):
                raise SourceError(
                    f"{folder}: groundtruth_rect.txt has {len(boxes)} boxes but img/ has {len(self.files)} "
                    f"frames; they must match one to one (remove extra lines or frames)"
                )
            # UAV123 comes from MATLAB and counts from 1 (see shared/data/README.md).
            shift = 1.0 if (one_based_truth if one_based_truth is not None else folder.name.startswith("uav123")) else 0.0
            self.truth = [None if b is None else (b[0] - shift, b[1] - shift, b[2], b[3]) for b in boxes]
        if n_frames is not None:
            self.files = self.files[:max(0, int(n_frames))]
            self.truth = None if self.truth is None else self.truth[:len(self.files)]
        self._size: tuple[int, int] | None = None
        """(width, height) of the first frame read: every frame must have it."""

    def __len__(self) -> int:
        return len(self.files)

    @property
    def has_truth(self) -> bool:
        return self.truth is not None

    def frame(self, i: int) -> Frame:
        from common.sources.imageio import ImageReadError, decode_rgb

        path = self.files[i]
        try:
            data = path.read_bytes()
            img = decode_rgb(data)
        except (OSError, ImageReadError):
            raise SourceError(f"{path}: not a readable image (OpenCV could not decode it)") from None
        size = (int(img.shape[1]), int(img.shape[0]))
        if self._size is None:
            self._size = size
        elif size != self._size:
            raise SourceError(f"{path}: {size[0]}x{size[1]} pixels, the folder's other frames "
                              f"{self._size[0]}x{self._size[1]}; every frame of a sequence must have one size "
                              f"(resize or remove this one)")
        truth = None
        if self.truth is not None:
            truth = GroundTruth(box=self.truth[i])
        fmt = {".jpg": "jpeg", ".jpeg": "jpeg", ".png": "png"}.get(path.suffix.lower())
        return Frame(index=i, time=i / self.fps, image=img, truth=truth,
                     encoded=(fmt, data) if fmt is not None else None)

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self)):
            yield self.frame(i)


def _captured(cap, limit: int | None, clock) -> Iterator[Frame]:
    """The frames an opened ``cv2.VideoCapture`` reads until it ends (at most ``limit``), frame i
    taken at ``clock(i)`` s; releases the capture."""
    i = 0
    try:
        while limit is None or i < limit:
            ok, bgr = cap.read()
            if not ok:
                break
            yield Frame(index=i, time=clock(i), image=np.ascontiguousarray(bgr[:, :, ::-1]))
            i += 1
    finally:
        cap.release()


class VideoSource(Source):
    image_format = "jpeg:90"

    def __init__(self, path: Path, n_frames: int | None = None):
        """``n_frames`` keeps only the first frames."""
        path = Path(path)
        if not path.exists():
            raise SourceError(f"{path}: no such file")
        cap = cv2.VideoCapture(str(path))
        ok, first = cap.read() if cap.isOpened() else (False, None)
        cap.release()
        if not ok or first is None:
            raise SourceError(f"{path}: not a readable video (OpenCV could not decode a frame)")
        self.path = path
        self.name = path.stem
        fps = cv2.VideoCapture(str(path)).get(cv2.CAP_PROP_FPS)
        self.fps = float(fps) if fps and fps > 0 else 30.0
        self.limit = None if n_frames is None else max(0, int(n_frames))

    def __iter__(self) -> Iterator[Frame]:
        yield from _captured(cv2.VideoCapture(str(self.path)), self.limit, lambda i: i / self.fps)

    def __len__(self) -> int:
        cap = cv2.VideoCapture(str(self.path))
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        cap.release()
        return n if self.limit is None else min(n, self.limit)


class CameraSource(Source):
    live = True
    image_format = "jpeg:90"

    def __init__(self, device: int, max_frames: int | None = None):
        self.device = device
        self.name = f"camera{device}"
        self.max_frames = max_frames

    def __iter__(self) -> Iterator[Frame]:
        cap = cv2.VideoCapture(self.device)
        if not cap.isOpened():
            raise SourceError(f"camera {self.device}: cannot be opened (is a camera attached?)")
        t0 = time.monotonic()
        yield from _captured(cap, self.max_frames, lambda i: time.monotonic() - t0)


class PrerenderedSource(WrappedSource):
    """A seekable source with every frame read (or, for the synthetic scene, rendered) up front and
    held in memory, so that publishing a frame costs what reading a recorded video does
    (``bench --pipeline`` by default: the pipeline without the scene renderer, about 22 ms of
    one core a 1280x720 frame); the frames are the same, bit for bit."""

    forwarded = ("true_centre",)

    def __init__(self, source: Source, max_bytes: int = 8 << 30):
        if not hasattr(source, "frame") or source.live:
            raise SourceError(f"{source.name}: only a seekable file or synthetic source can be prerendered")
        first = source.frame(0)
        need = first.image.nbytes * len(source)
        if need > max_bytes:
            raise SourceError(f"{source.name}: prerendering {len(source)} frames needs {need / 2**30:.1f} GiB "
                              f"(limit {max_bytes / 2**30:.1f} GiB); use fewer frames or no prerendering")
        super().__init__(source)
        self.frames = [first] + [source.frame(i) for i in range(1, len(source))]

    def __len__(self) -> int:
        return len(self.frames)

    def frame(self, i: int) -> Frame:
        return self.frames[i]

    def __iter__(self) -> Iterator[Frame]:
        yield from self.frames


class PeopleSource(Source):
    """The synthetic people scene (several walking people, per-part ground truth)."""

    def __init__(self, seed: int = 0, n_people: int = 3, n_frames: int | None = None):
        from common.scene.people import PeopleScene, PeopleSceneConfig

        cfg = PeopleSceneConfig(n_people=n_people, **({"n_frames": n_frames} if n_frames else {}))
        self.scene = PeopleScene(cfg, seed=seed)
        self.seed, self.n_people = seed, n_people
        self.name = f"people-{seed}"
        self.fps = float(cfg.fps)

    def __len__(self) -> int:
        return len(self.scene)

    def frame(self, i: int) -> Frame:
        f = self.scene.frame(i)
        return Frame(index=i, time=float(f.time), image=f.image, people=f.truth)

    def person_boxes(self) -> np.ndarray:
        """(people, 4) x, y, w, h boxes of the first frame (the default initialisation)."""
        return np.asarray(self.scene.frame(0).truth.boxes, float)

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self)):
            yield self.frame(i)


def open_people(spec: str, n_frames: int | None = None) -> PeopleSource:
    parts = spec.split(":")[1:]
    try:
        seed = int(parts[0]) if parts and parts[0] else 0
        people = int(parts[1]) if len(parts) > 1 else 3
        if len(parts) > 2:
            raise ValueError("too many fields")
        return PeopleSource(seed, people, n_frames)
    except ValueError as exc:
        raise SourceError(f"bad synthetic people source {spec!r} ({exc}); use people, people:SEED or "
                          f"people:SEED:PEOPLE (PEOPLE 1..5, at least 10 frames)") from None


def open_source(spec: str, n_frames: int | None = None) -> Source:
    """Open a source from its string (see the module docstring)."""
    spec = str(spec)
    if spec == "synthetic" or spec.startswith("synthetic:"):
        parts = spec.split(":")[1:]
        try:
            seed = int(parts[0]) if parts and parts[0] else 0
            length = int(parts[1]) if len(parts) > 1 else None
            if len(parts) > 2 or (length is not None and length < 2):
                raise ValueError
        except ValueError:
            raise SourceError(f"bad synthetic source {spec!r}: use synthetic, synthetic:SEED or "
                              f"synthetic:SEED:LENGTH (integers; LENGTH frames, default 300)") from None
        config = None
        if length is not None:
            from common.scene import SceneConfig

            try:
                config = SceneConfig(n_frames=length)
            except ValueError as exc:
                raise SourceError(f"bad synthetic source {spec!r}: {exc}") from None
        return SyntheticSource(seed=seed, n_frames=n_frames, config=config)
    if spec == "people" or spec.startswith("people:"):
        return open_people(spec, n_frames)
    for name in ("zoom", "exit"):
        if spec == name or spec.startswith(name + ":"):
            from common.scene.events import ExitSource, ZoomSource

            parts = spec.split(":")[1:]
            try:
                seed = int(parts[0] or 0) if parts else 0
                fps = float(parts[1]) if len(parts) > 1 and name == "exit" else None
                if len(parts) > (2 if name == "exit" else 1) or (fps is not None and not 1.0 <= fps <= 240.0):
                    raise ValueError
            except ValueError:
                form = "exit, exit:SEED or exit:SEED:FPS (FPS 1-240)" if name == "exit" else "zoom or zoom:SEED"
                raise SourceError(f"bad source {spec!r}: use {form} (SEED an integer)") from None
            if name == "zoom":
                src = ZoomSource(seed=seed)
            else:
                src = ExitSource(seed=seed) if fps is None else ExitSource(seed=seed, fps=fps)
            if n_frames is not None:
                src.n_frames = max(0, min(int(n_frames), src.n_frames))
            return src
    if spec.startswith("camera:"):
        try:
            return CameraSource(int(spec.partition(":")[2]), max_frames=n_frames)
        except ValueError:
            raise SourceError(f"bad camera {spec!r}: use camera:N with N the device number") from None
    path = Path(spec)
    if path.is_dir():
        return FolderSource(path, n_frames=n_frames)
    if path.exists():
        return VideoSource(path, n_frames=n_frames)
    raise SourceError(
        f"{spec}: no such file or folder (SOURCE is a video file, a UAV123-format folder, "
        f"camera:N, or synthetic[:SEED])"
    )
