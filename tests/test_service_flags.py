"""A service's flags are generated from its settings model (services.options.add_model_flags):
every field a command line can hold is a flag, with the field's description as its help, and a
flag reaches the validated settings as the config file's key would."""

import argparse

import pytest

from services import options
from services.deploy import SERVICES, model_class


@pytest.mark.parametrize("service", SERVICES)
def test_every_simple_field_is_a_flag(service):
    model = model_class(service)
    p = argparse.ArgumentParser()
    keys = options.add_model_flags(p, model)
    tables = {n for n, f in model.model_fields.items() if options.flag_type(f.annotation) is None}
    assert set(keys) == set(model.model_fields) - tables
    assert tables <= {"settings"}  # only the tracker's filter settings are a table (config file, run file)
    help_text = p.format_help()
    for name in keys:
        assert "--" + name.replace("_", "-") in help_text


def test_flags_reach_the_settings(tmp_path):
    from services.tracker import TrackerServiceSettings, run_keys

    p = argparse.ArgumentParser()
    options.add_bus_arguments(p)
    keys = options.add_model_flags(p, TrackerServiceSettings)
    args = p.parse_args(["--init-box", "1,2,3.5,4", "--max-lag-frames", "3", "--no-publish-particles",
                         "--query-timeout-s", "0.5"])
    _bus, cfg = options.load("tracker", args, TrackerServiceSettings, keys, run=run_keys)
    assert cfg.init_box == (1.0, 2.0, 3.5, 4.0) and cfg.max_lag_frames == 3 and cfg.publish_particles is False
    assert cfg.query_timeout_s == 0.5 and cfg.skip_stale is False  # unset flags keep the defaults
    with pytest.raises(SystemExit):
        p.parse_args(["--init-box", "1,2,3"])  # four numbers
    with pytest.raises(SystemExit) as exc:  # a value the model refuses: the one-line error, exit 2
        options.load("tracker", p.parse_args(["--init-box", "1,2,3,4", "--query-timeout-s", "-1"]),
                     TrackerServiceSettings, keys)
    assert exc.value.code == 2


def test_list_and_choice_flags():
    from services.ingest import IngestSettings

    p = argparse.ArgumentParser()
    options.add_model_flags(p, IngestSettings)
    args = p.parse_args(["--wait-for", "detector,tracker", "--pace", "max"])
    assert args.wait_for == ["detector", "tracker"] and args.pace == "max"
    with pytest.raises(SystemExit):
        p.parse_args(["--pace", "sometimes"])
