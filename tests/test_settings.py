"""Every settings model in common/ and services/ documents each of its fields: the description is the
help of the flags (services/options.py), the comment above the key in the TOML files
(services/deploy.py) and the knob's reference."""

import argparse
import importlib
import inspect
import pkgutil
from typing import Literal, get_args, get_origin

from pydantic import BaseModel

import common
import services

UNDOCUMENTED: set[str] = set()
"""Fields still without a description (documenting one adds a comment to its deploy/*.toml): take a
field off this list when it gets its docstring."""


def _settings_models() -> dict[str, type[BaseModel]]:
    """The pydantic models defined in common/ (the generated messages aside) and in services/ (the
    services' settings, the bus's), by qualified name."""
    found = {}
    for package in (common, services):
        for info in pkgutil.walk_packages(package.__path__, package.__name__ + "."):
            if info.name.startswith("common.msgs"):
                continue
            module = importlib.import_module(info.name)
            for obj in vars(module).values():
                if inspect.isclass(obj) and issubclass(obj, BaseModel) and obj.__module__ == module.__name__:
                    found[f"{obj.__module__}.{obj.__qualname__}"] = obj
    return found


def _needs_description(field) -> bool:
    """A nested table is documented by its own model, a discriminated union's tag by its value."""
    ann = field.annotation
    if inspect.isclass(ann) and issubclass(ann, BaseModel):
        return False
    return not (get_origin(ann) is Literal and len(get_args(ann)) == 1)


def test_every_settings_field_has_a_description():
    models = _settings_models()
    assert {"common.settings.TrackerSettings", "common.tracking.rbpf.RBPFConfig", "services.bus.BusConfig",
            "services.ingest.IngestSettings", "services.tracker.TrackerServiceSettings"} <= models.keys()
    missing = {f"{name}.{key}" for name, model in models.items()
               for key, field in model.model_fields.items()
               if _needs_description(field) and not (field.description or "").strip()}
    new, done = sorted(missing - UNDOCUMENTED), sorted(UNDOCUMENTED - missing)
    assert not new, f"fields without a description: {', '.join(new)}"
    assert not done, f"documented now, take them off UNDOCUMENTED: {', '.join(done)}"


def test_attribute_docstrings_are_the_descriptions():
    from common.multitarget.config import EvolutionConfig
    from common.tracking import RBPFConfig, SIRConfig

    assert EvolutionConfig.model_fields["crossover_prob"].description == (
        "rho_c, probability that a particle pair crosses over (per sweep, and in the sampling step).")
    # the base config's field, documented once for both particle filters
    assert RBPFConfig.model_fields["confine_to_image"].description == SIRConfig.model_fields["confine_to_image"].description
    assert RBPFConfig.model_fields["confine_to_image"].description.startswith("Pang 2010 §3 assumes")


def test_flag_help_is_one_paragraph():
    """A docstring over several lines gives a description with line breaks; a flag's help folds them."""
    from common.settings import RunSpec
    from services.commands.common_args import add_run_flags
    from services.options import add_model_flags, field_help

    assert "\n" in RunSpec.model_fields["pace"].description
    assert field_help(RunSpec.model_fields["pace"]) == " ".join(RunSpec.model_fields["pace"].description.split())
    p = argparse.ArgumentParser()
    add_run_flags(p, "frames")
    add_model_flags(p, RunSpec, skip=("frames",))
    helps = [a.help for a in p._actions if a.help]
    assert helps and all("\n" not in h and "  " not in h for h in helps)
