"""One home for each default: config.yaml. The schema types and describes the keys and defaults
only those config.yaml leaves unset; a library dataclass that a job fills from config.yaml keeps
defaults for callers outside the workflow, and those must be config.yaml's."""

import dataclasses

import pytest
import yaml

from spc3d.checkpoints import CheckpointPolicy
from spc3d.inputs.augment import AugmentSettings
from spc3d.physics.spc import SPCParams
from spc3d.reconstruct.objectives import JointConfig
from spc3d.translate.validate import ValidationSettings

from conftest import REPO

CONFIG = yaml.safe_load((REPO / "config.yaml").read_text())
SCHEMA = yaml.safe_load((REPO / "workflow" / "schemas" / "config.schema.yaml").read_text())


def schema_defaults(node: dict, path: tuple = ()):
    """(key path, default) of every ``default`` under ``properties`` (user-named entries, such as a
    capture's block, have no place in config.yaml and are not walked)."""
    if "default" in node:
        yield path, node["default"]
    for key, child in (node.get("properties") or {}).items():
        yield from schema_defaults(child, (*path, key))


def lookup(config: dict, path: tuple):
    for key in path:
        if not isinstance(config, dict) or key not in config:
            raise KeyError(".".join(path))
        config = config[key]
    return config


def test_no_key_has_a_default_in_both_config_yaml_and_the_schema():
    """A schema default of a key config.yaml sets never applies (config.yaml is read first) and drifts:
    stage1.validation's every 25 / patience 2 beside config.yaml's 50 / 4, the combinations without
    four of config.yaml's rows. An empty block ({}) only says the block may be left out."""
    both = []
    for path, default in schema_defaults(SCHEMA):
        try:
            lookup(CONFIG, path)
        except KeyError:
            continue
        if default != {}:
            both.append(".".join(path))
    assert not both, f"defaults in both config.yaml and the schema (keep config.yaml's): {both}"
    assert len(list(schema_defaults(SCHEMA))) > 10  # the walk reaches the schema's keys


@pytest.mark.parametrize(
    "settings, block, fields",
    [
        (ValidationSettings(), ("stage1", "validation"), ("every", "patience")),
        (JointConfig(), ("stage2", "joint"), ("weight", "weight_final", "decay_until")),
        (CheckpointPolicy(), ("checkpoints",), ("fraction", "minutes")),
        (AugmentSettings(), ("augment",), ("rotation_deg", "shear_deg", "flip_prob")),
        (SPCParams(), ("spc",), ("mode", "q", "tau_d", "exposure_s", "dark_count_rate")),
    ],
    ids=lambda v: type(v).__name__ if dataclasses.is_dataclass(v) else None,
)
def test_library_defaults_agree_with_config_yaml(settings, block, fields):
    """A job builds these from config.yaml; a test or benchmark that leaves a field out gets the
    dataclass default, which must then be the workflow's."""
    configured = lookup(CONFIG, block)
    assert {f: getattr(settings, f) for f in fields} == {f: configured[f] for f in fields}


def test_the_augmentation_zoom_range_agrees():
    assert list(AugmentSettings().zoom) == CONFIG["augment"]["zoom"]
