"""The Tracker's detector client: everything of a tracking step that needs pixels and the template.

:class:`common.single_target.runner.Tracker` keeps the bookkeeping (filter, stabiliser, scale, adaptation) and
asks a client for the matching:

- ``build_template(frame, centre, box, k)``: the template on the first frame, at factor ``k``;
- ``use_template(template)``: match with an adapted template from now on;
- ``observation(frame, homography, k)``: the frame's observation at factor ``k`` (what the filter
  queries, then the template adaptation's ``refine_peak`` / ``pmatrix_at`` at the estimate);
- ``scale_grid(frame, k, xy, crop)``: the scale search's and the re-acquisition's scores, each on a
  resampled crop of its own (over the hypotheses, or the ``crop`` box a query names: the queries of
  a frame that name the same box share its preparation).

:class:`LocalDetector` does it in-process. Over the bus and on offline replay the same
operations travel as queries (:mod:`common.detector.remote`), and the detector service answers
them with the functions below, called in the same order on the same pixels, so the numbers are
bit-identical.
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Protocol

import numpy as np

from common.detector.frame import FrameCache
from common.detector.matcher import PolarMatcher
from common.detector.observation import DetectorObservation
from common.detector.resample import ResampledObservation, footprint_inside, sample_template_pmatrix
from common.detector.template import Template, check_textured


def make_template(image: np.ndarray, centre: tuple[float, float], box: tuple[float, float, float, float],
                  k: float) -> Template:
    """The template at ``centre`` of ``image`` matched at resampling factor ``k``. Where the footprint
    passes the frame's edge (a target first boxed near it) the part beyond is read from the frame
    reflected across the edge, as a resampled crop is filled (:class:`common.detector.resample.ResampledRegion`;
    at ``k`` = 1 its coefficients are the full frame's, so the two ways agree wherever both apply)."""
    h, w = np.asarray(image).shape[:2]
    if k == 1.0 and footprint_inside(np.array([centre], float), 1.0, (w, h))[0]:
        return Template.from_image(image, centre, box=box)
    return Template(pmatrix=check_textured(sample_template_pmatrix(image, centre, k)), centre=centre,
                    box=tuple(float(v) for v in box))


def frame_observation(key: object, time: float, image: np.ndarray, matcher: PolarMatcher, cache: FrameCache,
                      k: float, homography: np.ndarray | None = None):
    """A frame's observation at factor ``k``: the plain full-resolution path (regions kept in
    ``cache`` under ``key``) when ``k`` is 1, else a resampled one (its crop kept by the object)."""
    if k == 1.0:
        return DetectorObservation(key, time, image, matcher, cache, homography)
    return ResampledObservation(key, time, image, matcher, k, homography)


def one_off_grid(time: float, image: np.ndarray, matcher: PolarMatcher, k: float, xy: np.ndarray,
                 crop: tuple[float, float, float, float] | None = None,
                 regions: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """48-angle scores at ``xy`` on a crop of ``image`` resampled by ``k``: over the hypotheses,
    or over ``crop`` (x0, y0, x1, y1, original pixels) with them (:func:`~common.detector.resample.crop_box`),
    that preparation kept in ``regions`` for the frame's later queries naming the same box. Either
    way the numbers depend on the frame, ``k``, the box and ``xy`` alone (the scale search's and the
    re-acquisition's measurements: unaffected by the frame's other queries). Only hypotheses whose
    whole footprint lies in the frame are scored: these measurements set the state outright (a
    restart's position, a scale correction), and a score that reads the reflection beyond the
    frame's edge is biased (the filter's per-frame scores may, weighed against its motion prior)."""
    return ResampledObservation(None, time, image, matcher, k, whole_footprint=True, crop=crop,
                                regions=regions).score_grid(xy)


class OneOffRegions:
    """The prepared crops that one-off queries named by box (:func:`one_off_grid`), for the latest
    frame of each client (a query about another frame drops the client's old ones), for at most
    ``max_clients`` clients (the least recently asking dropped first). The crops do not depend on
    the template: a template update keeps them."""

    def __init__(self, max_clients: int = 8):
        self.max_clients = max_clients
        self._by_client: OrderedDict[object, tuple[int, dict]] = OrderedDict()

    def of(self, client: object, frame_index: int) -> dict:
        held = self._by_client.get(client)
        if held is None or held[0] != frame_index:
            held = (int(frame_index), {})
            self._by_client[client] = held
        self._by_client.move_to_end(client)
        while len(self._by_client) > self.max_clients:
            self._by_client.popitem(last=False)
        return held[1]


class DetectorClient(Protocol):
    def build_template(self, frame, centre: tuple[float, float], box: tuple[float, float, float, float],
                       k: float) -> Template: ...

    def use_template(self, template: Template) -> None: ...

    def observation(self, frame, homography: np.ndarray | None, k: float): ...

    def scale_grid(self, frame, k: float, xy: np.ndarray,
                   crop: tuple[float, float, float, float] | None = None) -> tuple[np.ndarray, np.ndarray]: ...


class LocalDetector:
    """:class:`DetectorClient` in-process: the frames' pixels, the current matcher, a frame cache."""

    def __init__(self):
        self.cache = FrameCache()
        self.one_off = OneOffRegions()
        self.matcher: PolarMatcher | None = None

    def build_template(self, frame, centre, box, k: float) -> Template:
        template = make_template(frame.image, centre, box, k)
        self.use_template(template)
        return template

    def use_template(self, template: Template) -> None:
        self.matcher = PolarMatcher(template)  # prepared frames stay valid

    def observation(self, frame, homography, k: float):
        return frame_observation(frame.index, frame.time, frame.image, self.matcher, self.cache, k, homography)

    def scale_grid(self, frame, k: float, xy: np.ndarray,
                   crop: tuple[float, float, float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
        regions = None if crop is None else self.one_off.of(None, frame.index)
        return one_off_grid(frame.time, frame.image, self.matcher, k, xy, crop, regions)
