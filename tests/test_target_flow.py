"""The target's own change of size (median flow on its pixels) and its fusion with the camera's zoom."""

import math

import cv2
import numpy as np
import pytest

from common.settings import ScaleSettings
from common.single_target.scale import ScaleTracker
from common.single_target.target_flow import FlowMeasurement, TargetFlowConfig, measure_scale_change
from tests.test_scale import texture, zoomed

CENTRE = (320.0, 240.0)
W, H = 80.0, 50.0


def with_target(ground: np.ndarray, target: np.ndarray, scale: float, centre=CENTRE) -> np.ndarray:
    """``ground`` with the W x H ellipse of ``target`` (same size as ground, centred on CENTRE) pasted
    on it enlarged by ``scale`` about ``centre``."""
    tgt = zoomed(target, CENTRE, scale)
    m = cv2.getRotationMatrix2D(CENTRE, 0.0, 1.0)
    m[:, 2] += np.subtract(centre, CENTRE)
    tgt = cv2.warpAffine(tgt, m, (tgt.shape[1], tgt.shape[0]), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    mask = np.zeros(ground.shape[:2], np.uint8)
    cv2.ellipse(mask, (round(centre[0]), round(centre[1])), (round(W * scale / 2), round(H * scale / 2)), 0, 0, 360, 1, -1)
    out = ground.copy()
    out[mask == 1] = tgt[mask == 1]
    return out.astype(np.uint8)


@pytest.fixture(scope="module")
def images():
    return texture(seed=5), texture(seed=6)  # the ground, the target's own texture


@pytest.mark.parametrize("growth", [1.0, 1.06, 0.92])
def test_the_targets_own_growth_is_measured_while_the_ground_zooms_otherwise(images, growth):
    """The ground zooms by 1.15 about a point beside the target (a camera approaching the ground) while
    the target grows by ``growth``: the measurement is the target's, not the ground's."""
    ground, target = images
    cfg = TargetFlowConfig()
    prev = with_target(ground, target, 1.0)
    cur = with_target(zoomed(ground, (200.0, 150.0), 1.15), target, growth)
    m = measure_scale_change(cfg, prev, cur, (*CENTRE, W, H, 0.0))
    assert m is not None and m.points >= cfg.min_points
    assert m.dlog == pytest.approx(math.log(growth), abs=0.01), (m, math.log(growth))
    # its variance is honest: the error within 3 sigma, and no smaller than the points' noise floor
    assert abs(m.dlog - math.log(growth)) < 3 * math.sqrt(m.var)
    assert m.var >= (2 * math.sqrt(2) * cfg.point_noise_px / max(W, H)) ** 2


def test_a_moving_target_is_measured_with_the_cameras_motion_given(images):
    """The camera pans 30 px and the target moves 12 px more while growing 1.05: started at the camera's
    motion, the points find the target; the camera's zoom is not the answer."""
    ground, target = images
    pan = np.array([[1.0, 0.0, 30.0], [0.0, 1.0, -8.0], [0.0, 0.0, 1.0]])
    prev = with_target(ground, target, 1.0)
    moved = (CENTRE[0] + 30 + 12, CENTRE[1] - 8 + 5)
    cur = with_target(cv2.warpPerspective(ground, pan, (ground.shape[1], ground.shape[0]),
                                          borderMode=cv2.BORDER_REFLECT), target, 1.05, centre=moved)
    m = measure_scale_change(TargetFlowConfig(), prev, cur, (*CENTRE, W, H, 0.0), interframe=pan)
    assert m is not None and m.dlog == pytest.approx(math.log(1.05), abs=0.01), m


def test_no_measurement_on_a_textureless_target_or_a_degenerate_box(images):
    ground, _ = images
    flat = ground.astype(np.uint8).copy()
    cv2.ellipse(flat, (320, 240), (60, 40), 0, 0, 360, (90, 90, 90), -1)
    cfg = TargetFlowConfig()
    assert measure_scale_change(cfg, flat, flat, (*CENTRE, W, H, 0.0)) is None
    assert measure_scale_change(cfg, flat, flat, (*CENTRE, 0.0, H, 0.0)) is None
    assert measure_scale_change(cfg, flat, flat, (float("nan"), 240.0, W, H, 0.0)) is None
    assert measure_scale_change(cfg, flat, flat, (-5000.0, 240.0, W, H, 0.0)) is None


def _tracker(cfg=None):
    return ScaleTracker(cfg or ScaleSettings(), (100, 100, 40, 20), False, None, np.array([120.0, 110.0]), 0.0)


def test_prediction_fuses_the_zoom_and_the_targets_own_change_by_inverse_variance():
    cfg = ScaleSettings()
    dt, zoom = 0.1, 1.2
    h0, h1 = np.eye(3), np.diag([zoom, zoom, 1.0])
    own = FlowMeasurement(dlog=math.log(1.02), var=0.004, points=20)
    nu = own.dlog - math.log(zoom)
    a = dt / cfg.flow.departure_time_constant_s
    q = ((1 - a) * cfg.flow.departure_per_sqrt_s ** 2 + a * (nu * nu - own.var) / dt) * dt
    st = _tracker(cfg)
    st.predict(h0, h1, np.array([120.0, 110.0]), dt, own)
    assert math.log(st.s) == pytest.approx(math.log(zoom) + q / (q + own.var) * nu, abs=1e-12)
    assert 0 < q / (q + own.var) < 1 and st.flow_measurements == 1
    # without the target's own measurement the zoom alone; a certain measurement is taken as it is
    st = _tracker(cfg)
    st.predict(h0, h1, np.array([120.0, 110.0]), dt, None)
    assert st.s == pytest.approx(zoom) and st.flow_measurements == 0
    st = _tracker(cfg)
    st.predict(h0, h1, np.array([120.0, 110.0]), dt, FlowMeasurement(math.log(1.02), 1e-12, 20))
    assert st.s == pytest.approx(1.02, rel=1e-6)


def test_the_departure_is_learnt_from_the_innovations():
    """Two seconds at 30 fps, the camera zooming 0.5 % a frame, and the target's own measurement
    parting from the zoom by 3 % a frame (a car driving through an oblique view): the departure's
    variance is learnt (the prior forgotten over the time constant) and the scale follows the
    target, not the ground."""
    rng = np.random.default_rng(7)
    dt, r, z, frames = 1 / 30, 0.005 ** 2, 1.005, 60
    st = _tracker()
    h, truth = np.eye(3), 0.0
    for i in range(frames):
        nxt = h @ np.diag([z, z, 1.0])
        own_change = math.log(z) + 0.03
        truth += own_change
        st.predict(h, nxt, np.array([120.0, 110.0]), (i + 1) * dt,
                   FlowMeasurement(own_change + rng.normal(0, math.sqrt(r)), r, 20))
        h = nxt
    flow = ScaleSettings().flow
    kept = (1 - dt / flow.departure_time_constant_s) ** frames
    assert st.departure_q == pytest.approx(flow.departure_per_sqrt_s ** 2 * kept + 0.03 ** 2 / dt * (1 - kept), rel=0.2)
    ground = frames * math.log(z)
    assert abs(math.log(st.s) - truth) < 0.1 * abs(truth - ground)


def test_a_measurement_that_agrees_with_the_zoom_is_averaged_out():
    """Ten seconds of a still camera and a target of constant size, measured with white noise of
    1 % a frame (a camera over a flat road): the departure's variance falls (below a fifth of the
    measurement's by the end, so the zoom is kept), and over the last five seconds the scale
    wanders less than a third of the measurements' summed noise would take it."""
    rng = np.random.default_rng(7)
    dt, r, frames = 1 / 30, 0.01 ** 2, 300
    st = _tracker()
    h = np.eye(3)
    logs = []
    for i in range(frames):
        st.predict(h, h, np.array([120.0, 110.0]), (i + 1) * dt, FlowMeasurement(rng.normal(0, math.sqrt(r)), r, 20))
        logs.append(math.log(st.s))
    assert st.departure_q * dt < 0.2 * r
    assert abs(logs[-1] - logs[149]) < math.sqrt(150 * r) / 3
