"""The YAML under conf/ and the config dataclasses must carry the same defaults."""

import dataclasses
import math
from pathlib import Path

from hydra import compose, initialize_config_dir

from truckrl.env import EnvConfig

CONF = Path(__file__).resolve().parents[1] / "conf"


def _same(a, b, where="env"):
    """Field-by-field equality; floats to 1e-9 relative (YAML holds rounded radians)."""
    if dataclasses.is_dataclass(a):
        assert type(a) is type(b), where
        for f in dataclasses.fields(a):
            _same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, (tuple, list)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _same(x, y, f"{where}[{i}]")
    elif isinstance(a, float) or isinstance(b, float):
        assert math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12), f"{where}: {a} != {b}"
    else:
        assert a == b, f"{where}: {a!r} != {b!r}"


def test_env_yaml_defaults_equal_dataclass_defaults():
    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        cfg = compose(config_name=None, overrides=["+env=default", "+control=accel_rate"])
    _same(EnvConfig.from_hydra(cfg.env, cfg.control), EnvConfig())


def test_every_control_file_builds():
    names = sorted(p.stem for p in (CONF / "control").glob("*.yaml"))
    assert len(names) == 9
    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        for name in names:
            cfg = compose(config_name=None, overrides=["+env=default", f"+control={name}"])
            built = EnvConfig.from_hydra(cfg.env, cfg.control)
            assert f"{built.control.longitudinal}_{built.control.lateral}" == name
