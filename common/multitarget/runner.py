"""Multi-target tracking the same way in-process, in the tracker service and on offline replay.

:class:`MultiRun` is what a multi-target run is (method, :class:`MultiTargetConfig`, first-frame
person boxes, seed); :class:`MultiTracker` is its filter, stepped with a
:class:`~common.multitarget.appearance.PartEvidence` per frame: :class:`HistogramEvidence`
in-process (``track_frames``), :class:`~common.detector.remote.QueryPartEvidence` in the
tracker service (answered by the detector service) and on offline replay (answered by the
recorded replies). The filter only sees the evidence's answers, which are the same arrays
whichever way they come, so the estimates are bit-identical.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Iterable, Iterator

import numpy as np

from common.msgs import MultiEstimate, unpack
from common.msgs.convert import multi_estimate_msg
from common.multitarget import (HistogramEvidence, MultiTargetConfig, MultiTrackState,
                                PartEvidence, body_model, make_filter, method_config)
from common.multitarget.placement import start_from_boxes

@dataclass(frozen=True)
class MultiRun:
    """A multi-target run: ``method`` (one of :data:`common.multitarget.METHODS`), its config, the first frame's
    person boxes (T, 4) x, y, w, h, and the seed of the filter's generators."""

    method: str
    config: MultiTargetConfig
    boxes: tuple[tuple[float, float, float, float], ...]
    seed: int = 0

    @classmethod
    def make(cls, method: str, boxes, seed: int = 0, n_parts: int = 10, particles: int | None = None) -> "MultiRun":
        cfg = method_config(method, n_parts=n_parts, **({"n_particles": particles} if particles else {}))
        return cls(method, cfg, tuple(tuple(float(v) for v in b) for b in np.asarray(boxes, float)), int(seed))

    def to_json(self) -> str:
        return json.dumps({"method": self.method, "config": self.config.model_dump(mode="json"),
                           "boxes": [list(b) for b in self.boxes], "seed": self.seed})

    @classmethod
    def from_json(cls, text: str) -> "MultiRun":
        d = json.loads(text)
        return cls(d["method"], MultiTargetConfig.model_validate(d["config"]),
                   tuple(tuple(float(v) for v in b) for b in d["boxes"]), int(d["seed"]))


class MultiTracker:
    """The run's filter, started on the first frame's evidence (its ``image_size`` bounds the boxes):
    ``step(time, evidence) -> MultiTrackState``. Each body is placed in its box and shifted to where its core stands out from the surroundings
    (:mod:`common.multitarget.placement`; ``placement_shifts``, px)."""

    def __init__(self, run: MultiRun, first_evidence: PartEvidence):
        self.run = run
        self.body = body_model(run.config.n_parts)
        init, self.placement_shifts = start_from_boxes(np.array(run.boxes, float), self.body, first_evidence,
                                                       run.config.placement)  # fmt: skip
        self.filter = make_filter(run.config, init, first_evidence, run.seed)

    def step(self, frame_time: float, evidence: PartEvidence) -> MultiTrackState:
        return self.filter.step(frame_time, evidence)

    def prediction_msg(self, frame_index: int, frame_time: float, capture_ns: int | None = None,
                       step_ms: float = 0.0) -> MultiEstimate:
        """``observed=False``: the estimate of the particles as a failed step left them (its evidence
        did not come: the filter predicted, and weighed nothing), so a run without a detector still
        reports every frame."""
        from common.tracking import resampling

        f = self.filter
        parts, vel = f.estimate()
        t_n = len(parts)
        state = MultiTrackState(time=float(frame_time), parts=parts, velocity=vel,
                                n_eff=np.array([resampling.ess(row) for row in f.weights()]),
                                moved=np.zeros(t_n, bool), gate_area=np.zeros((t_n, 0)),
                                n_measurements=np.zeros((t_n, 0), np.int64), acceptance={})
        msg = multi_estimate_msg(frame_index, state, self.run, capture_ns, step_ms)
        msg.observed = False
        return msg


def track_frames(frames: Iterable, run: MultiRun) -> Iterator[tuple[object, MultiTrackState]]:
    """In-process: each frame's :class:`HistogramEvidence`, the filter started on the first."""
    tracker = None
    for frame in frames:
        ev = HistogramEvidence(frame.image, run.config.histogram)
        if tracker is None:
            tracker = MultiTracker(run, ev)
        yield frame, tracker.step(frame.time, ev)


def people_truth_parts(info, n_parts: int) -> np.ndarray | None:
    """(people, P, 2) true part centres of the body model from a FrameInfo's 10-point truth, or None."""
    if not info.truth_people:
        return None
    try:
        ten = unpack(info.truth_parts, np.float64, (info.truth_people, 10, 2))
    except ValueError:
        return None
    return body_model(n_parts).from_ten(ten)
