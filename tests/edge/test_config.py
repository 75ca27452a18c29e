import pytest

from edge.config import ConfigError, load_config


def test_defaults_are_valid_and_complete():
    cfg = load_config(env={})
    assert cfg["loop"].error_policy == "reconnect"
    assert cfg["source"].url.startswith("sim://simo")
    d = cfg.as_dict()
    assert "pipeline.minimal" in d and "loop" in d


def test_precedence_defaults_file_env_cli(tmp_path):
    f = tmp_path / "c.toml"
    f.write_text('[loop]\nerror_policy = "skip"\nmax_consecutive_errors = 7\n[pipeline.minimal]\nn_peaks = 3\n')
    cfg = load_config(f, env={})
    assert (cfg["loop"].error_policy, cfg["loop"].max_consecutive_errors, cfg["pipeline.minimal"].n_peaks) == ("skip", 7, 3)
    cfg = load_config(f, env={"RADAR_EDGE__LOOP__ERROR_POLICY": "stop", "OTHER": "x"})
    assert cfg["loop"].error_policy == "stop" and cfg["loop"].max_consecutive_errors == 7
    assert cfg.origin["loop.error_policy"] == "env RADAR_EDGE__LOOP__ERROR_POLICY"
    cfg = load_config(f, env={"RADAR_EDGE__LOOP__ERROR_POLICY": "stop"}, overrides={"loop.error_policy": "reconnect"})
    assert cfg["loop"].error_policy == "reconnect" and cfg.origin["loop.error_policy"] == "command line"


@pytest.mark.parametrize(
    "overrides, match",
    [
        ({"loop.error_policy": "panic"}, r"loop.error_policy = 'panic' is not allowed: choose one of skip, reconnect, stop"),
        ({"loop.max_consecutive_errors": "0"}, r"loop.max_consecutive_errors = 0 is out of range: allowed \[1, 1000000\]"),
        ({"loop.max_consecutive_errors": "2.5"}, r"loop.max_consecutive_errors: expected an integer"),
        ({"source.read_timeout_s": "abc"}, r"source.read_timeout_s: expected a number"),
        ({"loop.bogus": 1}, r"unknown key\(s\) loop.bogus"),
        ({"nosection.key": 1}, r"unknown configuration key 'nosection.key'"),
    ],
)
def test_bad_values_name_the_key_and_the_allowed_range(overrides, match):
    with pytest.raises(ConfigError, match=match):
        load_config(env={}, overrides=overrides)


def test_bad_file_is_an_error(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "nope.toml", env={})
    f = tmp_path / "bad.toml"
    f.write_text("[loop\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(f, env={})
    f.write_text("[lopo]\nx = 1\n")
    with pytest.raises(ConfigError, match="unknown configuration section or key 'lopo'"):
        load_config(f, env={})


def test_sections_are_frozen():
    cfg = load_config(env={})
    with pytest.raises(AttributeError):
        cfg["loop"].error_policy = "stop"
