"""The YAML under conf/ and the config dataclasses must carry the same defaults."""

from pathlib import Path

from hydra import compose, initialize_config_dir

from truckrl.env import EnvConfig

CONF = Path(__file__).resolve().parents[1] / "conf"


def test_env_yaml_defaults_equal_dataclass_defaults():
    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        cfg = compose(config_name=None, overrides=["+env=default", "+control=accel_rate"])
    assert EnvConfig.from_hydra(cfg.env, cfg.control) == EnvConfig()


def test_every_control_file_builds():
    names = sorted(p.stem for p in (CONF / "control").glob("*.yaml"))
    assert len(names) == 9
    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        for name in names:
            cfg = compose(config_name=None, overrides=["+env=default", f"+control={name}"])
            built = EnvConfig.from_hydra(cfg.env, cfg.control)
            assert f"{built.control.longitudinal}_{built.control.lateral}" == name
