"""The configuration: grouped settings validated at construction, loaded from TOML, every error naming its key."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from fuser.cli import main
from fuser.config import (
    MOVED,
    AccelSettings,
    AttitudeSettings,
    BiasSettings,
    FuserConfig,
    GyroSettings,
    MagSettings,
    RestSettings,
    load_config,
)

LOGS = Path(__file__).resolve().parent.parent / "logs"


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return repr(v)


def _toml(config: FuserConfig) -> str:
    """Every setting of ``config`` written out as TOML by hand (tomllib only reads)."""
    lines = ["[fuser]"]
    groups = []
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value):
            groups.append((f.name, value))
        elif value is not None:
            lines.append(f"{f.name} = {_toml_value(value)}")
    for name, group in groups:
        lines.append(f"[fuser.{name}]")
        lines += [f"{g.name} = {_toml_value(getattr(group, g.name))}" for g in dataclasses.fields(group)
                  if getattr(group, g.name) is not None]  # TOML has no null: an unset key is left out
    return "\n".join(lines) + "\n"


def test_every_group_and_key_loads_from_its_table(tmp_path):
    """The loader knows no group by name: a file with every key of every group gives exactly the config it was written from."""
    changed = FuserConfig(vehicle="v1", rate_hz=50.0, record="x.mcap", gyro=GyroSettings(noise_rad_s_rt_hz=1e-3),
                          mag=MagSettings(enabled=False, field_ned_gauss=(0.2, 0.01, 0.4)), attitude=AttitudeSettings(mode="always"))
    path = tmp_path / "all.toml"
    path.write_text(_toml(changed))
    assert load_config(path) == changed
    assert load_config(None) == FuserConfig()


def test_a_file_without_the_fuser_table_is_read_from_its_top_level(tmp_path):
    path = tmp_path / "flat.toml"
    path.write_text("latency_ms = 25\n[accel]\nlowpass_s = 2\n")
    config = load_config(path)
    assert config.latency_ms == 25.0 and config.accel.lowpass_s == 2.0


def test_the_logs_configs_are_in_the_new_layout():
    field = load_config(LOGS / "px4_sample_cut.toml").mag.field_ned_gauss
    assert field == (0.213695, 0.0, 0.429226)


@pytest.mark.parametrize("group, values, message", [
    (AccelSettings, {"lowpass_s": 0}, "fuser.accel.lowpass_s must be >= 0.001 s, got 0"),
    (AccelSettings, {"norm_gate_fraction": -0.1}, "fuser.accel.norm_gate_fraction must be > 0, got -0.1"),
    (GyroSettings, {"max_interval_s": -1.0}, "fuser.gyro.max_interval_s must be >= 0.001 s, got -1.0"),
    (GyroSettings, {"scale_error_fraction": 1.5}, "fuser.gyro.scale_error_fraction must be < 1, got 1.5"),
    (GyroSettings, {"noise_rad_s_rt_hz": float("nan")}, "fuser.gyro.noise_rad_s_rt_hz must be a finite number, got nan"),
    (BiasSettings, {"time_constant_s": 0.0}, "fuser.bias.time_constant_s must be >= 0.001 s, got 0.0"),
    (BiasSettings, {"feedback_enabled": 0}, "fuser.bias.feedback_enabled must be true or false, got 0"),
    (BiasSettings, {"floor_sigma_rad_s": 0.1}, "fuser.bias.floor_sigma_rad_s must be <= initial_sigma_rad_s"),
    (RestSettings, {"min_s": 0}, "fuser.rest.min_s must be >= 0.001 s, got 0"),
    (RestSettings, {"filter_s": "0.5"}, "fuser.rest.filter_s must be a number, got '0.5'"),
    (MagSettings, {"field_ned_gauss": (0.2, 0.0)}, "fuser.mag.field_ned_gauss must be a list of 3 values, got [0.2, 0.0]"),
    (MagSettings, {"field_ned_gauss": (0.0, 0.0, 0.0)}, "fuser.mag.field_ned_gauss must be a field a magnetometer reads"),
    # a damaged log's import once wrote this reference field: one corrupt sample in the mean of its first 2 s
    (MagSettings, {"field_ned_gauss": (153048249195.6, 0.0, 305775516277.5)}, "norm 0.001 to 10 gauss"),
    (MagSettings, {"field_ned_gauss": (1e-300, 0.0, 0.0)}, "norm 0.001 to 10 gauss"),  # divided by zero in the filter
    (MagSettings, {"fallback_field_ned_gauss": (0.0, 0.0, 1e-4)}, "fallback_field_ned_gauss must be a field"),
    (MagSettings, {"fallback_field_ned_gauss": (0.2, 0.0, -12.0)}, "fuser.mag.fallback_field_ned_gauss must be a field"),
    (MagSettings, {"field_ned_gauss": (0.2, "x", 0.4)}, "fuser.mag.field_ned_gauss[1] must be a number, got 'x'"),
    (AttitudeSettings, {"mode": "sometimes"}, "fuser.attitude.mode must be one of 'auto', 'always', 'off', got 'sometimes'"),
    (AttitudeSettings, {"sigma_deg": 0}, "fuser.attitude.sigma_deg must be >= 0.001 deg, got 0"),
    (FuserConfig, {"rate_hz": "fast"}, "fuser.rate_hz must be a number, got 'fast'"),
    (FuserConfig, {"latency_ms": -5}, "fuser.latency_ms must be >= 0 ms, got -5"),
    (FuserConfig, {"vehicle": 3}, "fuser.vehicle must be a string, got 3"),
    (FuserConfig, {"accel": {"lowpass_s": 2}}, "fuser.accel must be a AccelSettings ([fuser.accel]), got {'lowpass_s': 2}"),
])
def test_a_bad_value_is_refused_at_construction_naming_its_key(group, values, message):
    with pytest.raises(ValueError) as exc:
        group(**values)
    assert message in str(exc.value)


@pytest.mark.parametrize("text, message", [
    ('[fuser]\nrate_hz = "fast"\n', "fuser.rate_hz must be a number, got 'fast'"),
    ("[fuser.accel]\nlowpass_s = 0\n", "fuser.accel.lowpass_s must be >= 0.001 s, got 0"),
    ("[fuser]\naccel_lowpass_s = 2.0\n", "fuser.accel_lowpass_s has moved: set lowpass_s under [fuser.accel]"),
    ("[fuser]\nuse_mag = false\n", "fuser.use_mag has moved: set enabled under [fuser.mag]"),
    ("[fuser]\nmag_field_ned_gauss = [0.2, 0, 0.4]\n", "fuser.mag_field_ned_gauss has moved: set field_ned_gauss under [fuser.mag]"),
    ("[fuser]\nbias_time_constant_s = 0\n", "bias.feedback_enabled = false switches the feedback off"),
    ("[fuser]\nattitude_sigma_deg = 2\n", 'attitude.mode = "always" fuses the attitude'),
    ("[fuser.accel]\nlowpas_s = 2\n", "fuser.accel.lowpas_s is not a setting (did you mean lowpass_s?)"),
    ("[fuser]\naccel = 3\n", "fuser.accel must be a table [fuser.accel], got 3"),
    ("[fuser.mag]\nenabled = 1\n", "fuser.mag.enabled must be true or false, got 1"),
])
def test_a_bad_file_is_an_error_naming_the_file_and_the_key(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ValueError) as exc:
        load_config(path)
    assert str(exc.value).startswith(f"{path}: ") and message in str(exc.value)


def test_every_old_flat_key_names_a_setting_that_exists():
    config = FuserConfig()
    for old, new in MOVED.items():
        group, _, name = new.partition(".")
        assert hasattr(getattr(config, group), name), (old, new)


def test_a_key_moved_to_another_group_says_where(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("[fuser.bias]\nmotion_tilt_noise_deg = 0.5\n")
    with pytest.raises(ValueError, match=r"fuser\.bias\.motion_tilt_noise_deg has moved: set lowpass_error_deg under \[fuser\.accel\]"):
        load_config(path)
    assert not hasattr(FuserConfig().bias, "motion_tilt_noise_deg")


def test_overrides_use_dotted_keys_and_are_checked_like_the_file(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("[fuser.mag]\nenabled = true\nerror_deg = 3.0\n")
    config = load_config(path, {"mag.enabled": False, "rate_hz": 50, "vehicle": None})
    assert not config.mag.enabled and config.mag.error_deg == 3.0 and config.rate_hz == 50.0 and config.vehicle is None
    with pytest.raises(ValueError, match="fuser.accel.lowpass_s must be >= 0.001 s"):
        load_config(None, {"accel.lowpass_s": 0.0})


def test_replace_changes_a_group_by_a_mapping_and_validates():
    config = FuserConfig().replace(rate_hz=200.0, accel={"lowpass_s": 1.0})
    assert config.rate_hz == 200.0 and config.accel.lowpass_s == 1.0 and config.accel.sigma_rad == AccelSettings().sigma_rad
    with pytest.raises(ValueError, match="fuser.accel.lowpass_s"):
        config.replace(accel={"lowpass_s": -1.0})


def test_cli_with_a_bad_config_exits_2_with_one_line_naming_the_key(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('[fuser]\nrate_hz = "fast"\n')
    assert main(["replay", str(LOGS / "sim_hover.mcap"), "-o", str(tmp_path / "o.mcap"), "--config", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "fuser.rate_hz must be a number, got 'fast'" in err[0]


def test_cli_flags_map_onto_the_groups():
    """``_config`` turns the command line's flags into settings (the attitude policy's switches among them)."""
    import argparse

    from fuser.cli import _config

    base = dict(config=None, vehicle="v", rate_hz=50.0, no_mag=True, zenoh_listen=["tcp/127.0.0.1:9"], zenoh_connect=None)
    config = _config(argparse.Namespace(**base, attitude_sigma_deg=1.5))
    assert (config.vehicle, config.rate_hz, config.mag.enabled, config.zenoh.listen) == ("v", 50.0, False, ("tcp/127.0.0.1:9",))
    assert (config.attitude.mode, config.attitude.sigma_deg) == ("always", 1.5)
    assert _config(argparse.Namespace(**base, no_attitude=True)).attitude.mode == "off"
    assert _config(argparse.Namespace(**base)).attitude.mode == "auto"
