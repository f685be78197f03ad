"""--set KEY=VALUE overrides of the tracker settings on track / eval / run."""

import argparse

import pytest

from services.cli import main
from services.commands.common_args import settings_for
from common.sources import open_source


def args(*overrides):
    return argparse.Namespace(seed=0, particles=None, ml_threshold=None, overrides=list(overrides))


def test_overrides_reach_the_settings():
    src = open_source("synthetic:0", n_frames=2)
    st = settings_for(args("adaptation.enabled=true", "scale.mode=search", "scale.target_size_px=null",
                           "stabilise=off", "rbpf.n_particles=50", "motion_noise_lengths=2.5"), src, "rbpf")
    assert st.adaptation.enabled and st.scale.mode == "search" and st.scale.target_size_px is None
    assert st.stabilise == "off" and st.rbpf.n_particles == 50 and st.motion_noise_lengths == 2.5


@pytest.mark.parametrize("item, message", [
    ("scale.nope=1", "no setting 'scale.nope'"),
    ("scale.mode=sideways", "scale.mode: Input should be"),
    ("stabilise", "expected KEY=VALUE"),
    ("seed.x=1", "is not a group of settings"),
])
def test_bad_overrides_are_one_line_errors(capsys, item, message):
    assert main(["track", "synthetic:1", "--frames", "2", "--set", item, "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_run_takes_the_same_overrides(capsys):
    """run validates --set as track does (before starting any process)."""
    assert main(["run", "--source", "synthetic:1", "--frames", "2", "--set", "scale.mode=sideways"]) == 2
    assert "scale.mode: Input should be" in capsys.readouterr().err


def test_one_particle_knob_and_older_settings_read_the_same():
    """The particle count is the filter's own; ``--particles`` and the profile set both particle
    filters'. Settings recorded before had a top-level ``particles`` that replaced the filters'
    counts: read back, it is the same count (and a bad one is still refused)."""
    import pydantic

    from common.settings import TrackerSettings, profile_for

    src = open_source("synthetic:0", n_frames=2)
    st = profile_for(src, particles=123)
    assert st.rbpf.n_particles == st.sir.n_particles == 123 and "particles" not in st.model_dump()
    assert profile_for(src).rbpf.n_particles == 200 and profile_for(src).sir.n_particles == 300  # the papers'
    old = TrackerSettings.model_validate_json('{"filter": "sir", "particles": 400, "sir": {"n_particles": 300}}')
    assert old.sir.n_particles == old.rbpf.n_particles == 400
    assert TrackerSettings.model_validate_json('{"particles": null}') == TrackerSettings()
    with pytest.raises(pydantic.ValidationError):
        TrackerSettings.model_validate_json('{"particles": 0}')


def test_the_profiles_are_named_presets(tmp_path):
    """The real-footage profile is data (common.settings.PRESETS), chosen by the source or by name
    (``--profile``); a preset is the same settings as the overrides it lists over Pang's model at
    the frame rate."""
    import typing

    from common.settings import PRESETS, ProfileName, profile_for, rate_adjusted_settings, with_overrides

    assert set(typing.get_args(ProfileName)) == set(PRESETS)  # the flag's choices are the presets

    src = open_source("synthetic:0", n_frames=2)
    real = profile_for(src, preset="real")
    assert real.adaptation.enabled and real.reacquisition.enabled and real.rbpf.n_particles == 400
    assert not profile_for(src).adaptation.enabled  # the built-in scene gets "synthetic"
    assert real == with_overrides(rate_adjusted_settings(src.fps), PRESETS["real"])
    with pytest.raises(ValueError, match="no profile"):
        profile_for(src, preset="nope")
    out = tmp_path / "real.csv"
    assert main(["track", "synthetic:0", "--frames", "3", "--profile", "real", "--no-progress", "--out", str(out)]) == 0
    synth = tmp_path / "synth.csv"
    assert main(["track", "synthetic:0", "--frames", "3", "--no-progress", "--out", str(synth)]) == 0
    assert out.read_text() != synth.read_text()  # the profile reached the tracker
    with pytest.raises(SystemExit):
        main(["track", "synthetic:0", "--profile", "nope"])
