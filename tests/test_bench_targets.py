"""`polartrack bench --pipeline`'s verdict on issue 4's targets."""


def test_pipeline_targets():
    """The bench's verdict on issue 4's targets, at and around each limit."""
    import numpy as np

    from services.commands.bench import meets_targets

    lat = np.array([10.0, 40.0, 300.0])  # p50 40 ms
    assert meets_targets(30.0, lat, 0, 0)["meets_targets"]
    assert meets_targets(29.86, lat, 0, 0)["meets_targets"]  # the rate's ends
    r = meets_targets(29.8, lat, 0, 0)
    assert not r["meets_targets"] and r["targets_met"] == {"fps": False, "frames_dropped": True,
                                                         "latency_ms_p50": True, "frames_missing_from_recording": True}
    assert not meets_targets(30.0, lat, 0, 1)["targets_met"]["frames_dropped"]
    assert not meets_targets(30.0, lat, 1, 0)["targets_met"]["frames_missing_from_recording"]
    assert not meets_targets(30.0, np.array([10.0, 60.0, 70.0]), 0, 0)["targets_met"]["latency_ms_p50"]
    assert not meets_targets(30.0, np.array([]), 0, 0)["meets_targets"]  # no estimate at all
