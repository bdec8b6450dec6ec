"""Tests of the run configuration (nanoslam_jax.app.config): loading, overrides, validation, data directory."""

import dataclasses
from pathlib import Path

import pytest
import yaml

import nanoslam_jax.app.config as config_module
from nanoslam_jax.app.config import (
    DATASET_HELP,
    Config,
    ConfigError,
    FilterConfig,
    apply_overrides,
    config_from_dict,
    config_to_dict,
    load_config,
    resolve_data_dir,
)
from tests.helpers.paths import REPO_ROOT

ROOT = REPO_ROOT
# Run configs; comparisons (``methods``), sweeps (``grid``, ``random``) and studies (``study``) have
# their own schemas and tests.
CONFIGS = sorted(
    p
    for p in (ROOT / "configs").glob("*.yaml")
    if not {"methods", "grid", "random", "study"} & set(yaml.safe_load(p.read_text()) or {})
)


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


# --------------------------------------------------------------------------- loading


def test_embedded_default_is_nano_on_a_simulated_log():
    cfg = load_config()
    assert isinstance(cfg, Config)
    assert cfg.name == "default"
    assert cfg.data.kind == "simulated"
    assert cfg.filter.method == "nano"


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.name)
def test_shipped_configs_load_and_take_their_name_from_the_file(path):
    cfg = load_config(path)
    assert cfg.name == path.stem
    assert cfg.data.kind == ("indoor" if "indoor" in path.stem else "victoria_park")  # indoor: simulated in memory


def test_shipped_configs_say_what_they_run():
    assert load_config(ROOT / "configs" / "dead_reckoning.yaml").filter.method == "dead_reckoning"
    nano = load_config(ROOT / "configs" / "victoria_park_nano.yaml")
    assert nano.filter.method == "nano"
    assert nano.filter.n_particles == 10
    assert nano.data.max_range == 30.0


def test_yaml_values_are_typed_and_missing_keys_take_defaults(tmp_path):
    p = _write(tmp_path / "mine.yaml", "seed: 4\nfilter:\n  n_particles: 7\nnoise:\n  sigma_v: 1\n")
    cfg = load_config(p)
    assert cfg.name == "mine" and cfg.seed == 4
    assert cfg.filter.n_particles == 7 and type(cfg.filter.n_particles) is int
    assert cfg.noise.sigma_v == 1.0 and type(cfg.noise.sigma_v) is float  # an int is accepted for a float
    assert cfg.filter.capacity == FilterConfig().capacity
    assert cfg.nano == Config().nano


def test_explicit_name_in_yaml_wins_over_the_file_name(tmp_path):
    assert load_config(_write(tmp_path / "file.yaml", "name: chosen\n")).name == "chosen"


def test_empty_yaml_gives_defaults(tmp_path):
    cfg = load_config(_write(tmp_path / "empty.yaml", ""))
    assert cfg == dataclasses.replace(Config(), name="empty")


def test_missing_config_file_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="not found") as e:
        load_config(tmp_path / "nope.yaml")
    assert "nope.yaml" in str(e.value)


# --------------------------------------------------------------------------- overrides


def test_set_overrides_the_file_and_the_default(tmp_path):
    p = _write(tmp_path / "c.yaml", "filter:\n  n_particles: 7\n")
    cfg = load_config(
        p,
        [
            "filter.n_particles=20",
            "nano.quadrature=gauss_hermite",
            "noise.sigma_r=0.25",
            "map.manage=false",
            "data.t_end=30",
        ],
    )
    assert cfg.filter.n_particles == 20
    assert cfg.nano.quadrature == "gauss_hermite"
    assert cfg.noise.sigma_r == 0.25
    assert cfg.map.manage is False
    assert cfg.data.t_end == 30.0
    assert load_config(None, ["filter.n_particles=20"]).filter.n_particles == 20


def test_later_set_wins_and_null_resets_an_optional():
    cfg = load_config(None, ["filter.n_particles=3", "filter.n_particles=5", "data.t_end=30", "data.t_end=null"])
    assert cfg.filter.n_particles == 5
    assert cfg.data.t_end is None


def test_set_value_may_contain_an_equals_sign_and_spaces_around_the_key():
    cfg = load_config(None, ["name=a=b", " filter.n_particles = 4"])
    assert cfg.name == "a=b"
    assert cfg.filter.n_particles == 4


def test_apply_overrides_does_not_modify_its_input():
    raw = {"filter": {"n_particles": 7}}
    out = apply_overrides(raw, ["filter.n_particles=9"])
    assert raw == {"filter": {"n_particles": 7}}
    assert out == {"filter": {"n_particles": 9}}


def test_set_accepts_exponent_notation_without_a_dot(tmp_path):
    assert load_config(None, ["nano.gamma=1e-5"]).nano.gamma == 1e-5
    assert load_config(_write(tmp_path / "g.yaml", "nano:\n  gamma: 2e-4\n")).nano.gamma == 2e-4


def test_set_into_a_section_left_empty_in_the_yaml(tmp_path):
    p = _write(tmp_path / "c.yaml", "filter:\nseed: 1\n")
    assert load_config(p, ["filter.n_particles=3"]).filter.n_particles == 3


# --------------------------------------------------------------------------- validation


def _error(overrides=(), path=None) -> str:
    with pytest.raises(ConfigError) as e:
        load_config(path, list(overrides))
    return str(e.value)


@pytest.mark.parametrize(
    "item, key",
    [
        ("n_partcles=3", "n_partcles"),
        ("filter.n_partcles=3", "filter.n_partcles"),
        ("filtr.n_particles=3", "filtr.n_particles"),
        ("nano.quadrature.order=3", "nano.quadrature"),
    ],
)
def test_unknown_key_in_set_is_named(item, key):
    assert key in _error([item])


def test_unknown_key_in_set_lists_the_known_keys():
    msg = _error(["filter.n_partcles=3"])
    assert "unknown" in msg
    assert "n_particles" in msg.split("filter.n_partcles", 1)[1]


def test_setting_a_whole_section_is_rejected():
    msg = _error(["filter=3"])
    assert "'filter'" in msg and "section" in msg


@pytest.mark.parametrize(
    "text, key",
    [
        ("n_partcles: 3\n", "n_partcles"),
        ("filter:\n  n_partcles: 3\n", "filter.n_partcles"),
        ("nano:\n  quadratur: cubature\n", "nano.quadratur"),
    ],
)
def test_unknown_key_in_yaml_is_named_with_the_file(tmp_path, text, key):
    p = _write(tmp_path / "typo.yaml", text)
    msg = _error(path=p)
    assert key in msg
    assert "typo.yaml" in msg
    assert "unknown" in msg


@pytest.mark.parametrize(
    "item, key, expected",
    [
        ("filter.n_particles=abc", "filter.n_particles", "integer"),
        ("filter.n_particles=2.5", "filter.n_particles", "integer"),
        ("filter.n_particles=true", "filter.n_particles", "integer"),
        ("noise.sigma_v=true", "noise.sigma_v", "number"),
        ("noise.sigma_v=fast", "noise.sigma_v", "number"),
        ("noise.sigma_v=.nan", "noise.sigma_v", "finite"),
        ("map.manage=1", "map.manage", "true or false"),
        ("name=3", "name", "string"),
        ("data.path=[1, 2]", "data.path", "string"),
    ],
)
def test_wrong_type_is_named(item, key, expected):
    msg = _error([item])
    assert f"'{key}'" in msg
    assert expected in msg


def test_wrong_type_in_yaml_names_the_file_and_key(tmp_path):
    p = _write(tmp_path / "types.yaml", "filter:\n  n_particles: ten\n")
    msg = _error(path=p)
    assert "types.yaml" in msg and "filter.n_particles" in msg and "integer" in msg


def test_a_section_that_is_not_a_mapping_is_rejected(tmp_path):
    msg = _error(path=_write(tmp_path / "s.yaml", "filter: 3\n"))
    assert "'filter'" in msg and "mapping" in msg


@pytest.mark.parametrize(
    "item, key",
    [
        ("filter.n_particles=0", "filter.n_particles"),
        ("filter.n_particles=-4", "filter.n_particles"),
        ("noise.sigma_r=-1", "noise.sigma_r"),
        ("noise.sigma_v=0", "noise.sigma_v"),
        ("noise.sigma_beta_deg=-0.5", "noise.sigma_beta_deg"),
        ("filter.resample_threshold=1.5", "filter.resample_threshold"),
        ("filter.resample_threshold=-0.1", "filter.resample_threshold"),
        ("nano.gh_order=11", "nano.gh_order"),
        ("seed=-1", "seed"),
        ("data.t_end=0", "data.t_end"),
    ],
)
def test_out_of_range_is_named(item, key):
    msg = _error([item])
    assert f"'{key}'" in msg
    assert "expected a value" in msg


def test_range_boundaries_are_accepted():
    cfg = load_config(
        None,
        [
            "filter.n_particles=1",
            "filter.resample_threshold=1.0",
            "filter.resample_threshold=0",
            "nano.step=1.0",
            "data.min_range=0",
        ],
    )
    assert cfg.filter.n_particles == 1 and cfg.filter.resample_threshold == 0.0


def test_unknown_literal_lists_the_allowed_values():
    msg = _error(["filter.method=foo"])
    assert "'filter.method'" in msg and "'foo'" in msg
    for allowed in ("dead_reckoning", "nano", "fastslam1", "fastslam2"):
        assert repr(allowed) in msg
    msg = _error(["nano.quadrature=simpson"])
    assert all(repr(q) in msg for q in ("cubature", "unscented", "gauss_hermite"))


@pytest.mark.parametrize("item", ["filter.n_particles", "filter.n_particles:3", ""])
def test_malformed_set_is_rejected(item):
    msg = _error([item])
    assert "key=value" in msg
    if item:
        assert item in msg


def test_invalid_yaml_names_the_file_and_line(tmp_path):
    p = _write(tmp_path / "broken.yaml", "name: x\nfilter:\n  n_particles: 3\n   method: nano\nseed: 1\n")
    msg = _error(path=p)
    assert "broken.yaml" in msg
    assert "line 4" in msg
    assert "YAML" in msg


def test_unclosed_bracket_yaml_is_a_config_error(tmp_path):
    p = _write(tmp_path / "open.yaml", "filter:\n  method: [nano\n")
    msg = _error(path=p)
    assert "open.yaml" in msg and "line" in msg


def test_top_level_list_is_rejected(tmp_path):
    p = _write(tmp_path / "list.yaml", "- filter\n- nano\n")
    msg = _error(path=p)
    assert "list.yaml" in msg
    assert "mapping" in msg and "list" in msg


def test_top_level_scalar_is_rejected(tmp_path):
    msg = _error(path=_write(tmp_path / "scalar.yaml", "42\n"))
    assert "scalar.yaml" in msg and "mapping" in msg


@pytest.mark.parametrize(
    "items",
    [
        ["data.min_range=40"],
        ["data.min_range=30", "data.max_range=30"],
        ["data.min_range=5", "data.max_range=2"],
    ],
)
def test_min_range_must_be_below_max_range(items):
    msg = _error(items)
    assert "data.min_range" in msg and "data.max_range" in msg


def test_new_landmark_threshold_must_not_be_below_the_gate():
    msg = _error(["filter.gate=20", "filter.new_landmark=10"])
    assert "filter.new_landmark" in msg


@pytest.mark.parametrize(
    "items, key",
    [
        (["map.p_false=0.9", "map.p_detect=0.8"], "map.p_false"),
        (["map.birth_probability=0.01", "map.remove_probability=0.05"], "map.birth_probability"),
        (["map.birth_probability=0.999", "map.max_probability=0.99"], "map.birth_probability"),
        (["map.confirm_probability=0.999", "map.max_probability=0.99"], "map.confirm_probability"),
    ],
)
def test_inconsistent_landmark_management_is_named(items, key):
    msg = _error(items)
    assert f"'{key}'" in msg


def test_inconsistent_management_keys_are_accepted_with_management_off():
    cfg = load_config(None, ["map.manage=false", "map.p_false=0.9", "map.p_detect=0.8"])
    assert cfg.map.p_false == 0.9


@pytest.mark.parametrize(
    "items, fragments",
    [
        (["noise.forgetting=1.0"], ["noise.forgetting", "< 1"]),
        (["noise.forgetting=0"], ["noise.forgetting", "> 0"]),
        (["noise.adaptive_floor=1.5"], ["noise.adaptive_floor", "<= 1"]),
        (
            ["noise.adaptive=true", "filter.method=ekf_slam"],
            ["noise.adaptive", "ekf_slam", "nasrukf", "nano", "ufastslam"],
        ),
        (["noise.adaptive=true", "filter.method=fastslam1"], ["noise.adaptive", "fastslam1"]),
        (["nasrukf.feature=line"], ["nasrukf.feature", "'point'", "'arc'"]),
        (["nasrukf.new_feature_hits=0"], ["nasrukf.new_feature_hits", ">= 1"]),
    ],
)
def test_adaptive_noise_and_nasrukf_keys_are_validated(items, fragments):
    msg = _error(items)
    for f in fragments:
        assert f in msg, (f, msg)


def test_config_error_is_a_value_error():
    assert issubclass(ConfigError, ValueError)


# --------------------------------------------------------------------------- frozen, round trip


def test_config_is_frozen():
    cfg = load_config()
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.filter.n_particles = 3
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.seed = 1
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.filter = FilterConfig(n_particles=3)
    assert cfg.filter.n_particles != 3 and cfg == load_config()


def test_config_is_hashable_and_compares_by_value():
    a, b = load_config(None, ["filter.n_particles=3"]), load_config(None, ["filter.n_particles=3"])
    assert a == b and hash(a) == hash(b)
    assert a != load_config(None, ["filter.n_particles=4"])


def _all_configs():
    return [
        Config(),
        load_config(),
        *(load_config(p) for p in CONFIGS),
        load_config(None, ["filter.n_particles=3", "data.t_end=12.5", "data.path=/x/y"]),
        load_config(None, ["filter.init_cov=1.0e-12", "metrics.gps_rotation_deg=-33.0", "sim.seed=7"]),
    ]


@pytest.mark.parametrize("cfg", _all_configs())
def test_dict_round_trip(cfg):
    d = config_to_dict(cfg)
    assert isinstance(d, dict) and isinstance(d["filter"], dict)
    assert config_from_dict(d) == cfg


@pytest.mark.parametrize("cfg", _all_configs())
def test_yaml_round_trip(cfg):
    text = yaml.safe_dump(config_to_dict(cfg), sort_keys=False)
    assert config_from_dict(yaml.safe_load(text)) == cfg


def test_config_from_dict_validates_and_names_the_source():
    with pytest.raises(ConfigError, match="somewhere.yaml: unknown key 'filter.n_partcles'"):
        config_from_dict({"filter": {"n_partcles": 3}}, source="somewhere.yaml")
    assert config_from_dict({}) == Config()
    assert config_from_dict(None) == Config()


# --------------------------------------------------------------------------- data directory


@pytest.fixture
def dirs(tmp_path, monkeypatch):
    """Three existing directories (cli, cfg, env), cwd in an empty work dir, no NANOSLAM_DATA."""
    out = {}
    for name in ("cli", "cfg", "env"):
        out[name] = tmp_path / name
        out[name].mkdir()
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    monkeypatch.delenv("NANOSLAM_DATA", raising=False)
    return out


def _cfg_with_path(path):
    return load_config(None, [f"data.path={path}"]) if path else load_config()


def test_data_dir_cli_wins_over_config_and_env(dirs, monkeypatch):
    monkeypatch.setenv("NANOSLAM_DATA", str(dirs["env"]))
    assert resolve_data_dir(_cfg_with_path(dirs["cfg"]), str(dirs["cli"])) == dirs["cli"]


def test_data_dir_config_wins_over_env(dirs, monkeypatch):
    monkeypatch.setenv("NANOSLAM_DATA", str(dirs["env"]))
    assert resolve_data_dir(_cfg_with_path(dirs["cfg"]), None) == dirs["cfg"]


def test_data_dir_env_wins_over_the_default(dirs, monkeypatch, tmp_path):
    (tmp_path / "shared" / "data" / "victoria_park").mkdir(parents=True)  # the default, relative to cwd
    monkeypatch.setenv("NANOSLAM_DATA", str(dirs["env"]))
    assert resolve_data_dir(load_config(), None) == dirs["env"]


def test_data_dir_default_relative_to_the_working_directory(dirs, tmp_path):
    default = tmp_path / "shared" / "data" / "victoria_park"
    default.mkdir(parents=True)
    assert resolve_data_dir(load_config(), None).resolve() == default.resolve()


def test_data_dir_default_falls_back_to_the_project_root(dirs, monkeypatch, tmp_path):
    # cwd is tmp_path/work: tmp_path/shared/... does not exist; the project root is tmp_path/x/proj
    project = tmp_path / "x" / "proj"
    monkeypatch.setattr(config_module, "__file__", str(project / "nanoslam_jax" / "config.py"))
    with pytest.raises(FileNotFoundError):
        resolve_data_dir(load_config(), None)
    default = tmp_path / "x" / "shared" / "data" / "victoria_park"
    default.mkdir(parents=True)
    assert resolve_data_dir(load_config(), None).resolve() == default.resolve()


def _check_help(msg: str):
    assert "Victoria Park" in msg
    assert "--data" in msg
    assert "NANOSLAM_DATA" in msg


@pytest.mark.parametrize("origin", ["--data", "data.path", "NANOSLAM_DATA"])
def test_missing_data_dir_explains_how_to_get_the_dataset(dirs, monkeypatch, tmp_path, origin):
    missing = tmp_path / "nowhere"
    cli, cfg = None, load_config()
    if origin == "--data":
        cli = str(missing)
    elif origin == "data.path":
        cfg = _cfg_with_path(missing)
    else:
        monkeypatch.setenv("NANOSLAM_DATA", str(missing))
    with pytest.raises(FileNotFoundError) as e:
        resolve_data_dir(cfg, cli)
    msg = str(e.value)
    _check_help(msg)
    assert str(missing) in msg
    assert origin in msg


def test_missing_explicit_dir_does_not_fall_through_to_a_lower_precedence(dirs, monkeypatch, tmp_path):
    monkeypatch.setenv("NANOSLAM_DATA", str(dirs["env"]))
    with pytest.raises(FileNotFoundError):
        resolve_data_dir(_cfg_with_path(dirs["cfg"]), str(tmp_path / "typo"))


def test_no_data_dir_anywhere_explains_how_to_get_the_dataset(dirs, monkeypatch, tmp_path):
    monkeypatch.setattr(config_module, "__file__", str(tmp_path / "proj" / "nanoslam_jax" / "config.py"))
    with pytest.raises(FileNotFoundError) as e:
        resolve_data_dir(load_config(), None)
    _check_help(str(e.value))


def test_dataset_help_says_where_to_get_the_files():
    _check_help(DATASET_HELP)
    for name in ("inputs.dat", "measurements.dat", "gps.dat"):
        assert name in DATASET_HELP


# ----------------------------------------------------------------------------- base configs


def test_base_config_is_merged_section_by_section(tmp_path):
    (tmp_path / "a.yaml").write_text(
        "name: a\nnoise: {sigma_v: 1.5, sigma_r: 0.7}\nfilter: {method: nano, gate: 9.0}\n"
    )
    (tmp_path / "b.yaml").write_text("base: a.yaml\nfilter: {method: fastslam2}\nnoise: {sigma_r: 0.2}\n")
    cfg = load_config(tmp_path / "b.yaml", ["filter.gate=7.0"])
    assert cfg.name == "b"  # named after its own file
    assert cfg.filter.method == "fastslam2" and cfg.filter.gate == 7.0
    assert cfg.noise.sigma_v == 1.5 and cfg.noise.sigma_r == 0.2


def test_base_config_errors_name_the_file(tmp_path):
    (tmp_path / "b.yaml").write_text("base: missing.yaml\n")
    with pytest.raises(ConfigError, match=r"missing\.yaml: config file not found \(base of .*b\.yaml\)"):
        load_config(tmp_path / "b.yaml")
    (tmp_path / "c.yaml").write_text("base: d.yaml\n")
    (tmp_path / "d.yaml").write_text("base: c.yaml\n")
    with pytest.raises(ConfigError, match="cycle"):
        load_config(tmp_path / "c.yaml")
    (tmp_path / "e.yaml").write_text("base: 3\n")
    with pytest.raises(ConfigError, match=r"e\.yaml: key 'base'"):
        load_config(tmp_path / "e.yaml")


@pytest.mark.parametrize("method", ["fastslam1", "fastslam2", "ufastslam", "iterated", "ekf_slam", "nasrukf"])
def test_method_configs_differ_from_nano_only_in_method(method):
    root = REPO_ROOT / "configs"
    nano = config_to_dict(load_config(root / "victoria_park_nano.yaml"))
    other = config_to_dict(load_config(root / f"victoria_park_{method}.yaml"))
    assert other["filter"]["method"] == method
    assert other["name"] == f"victoria_park_{method}"
    for section in ("noise", "data", "vehicle", "metrics"):
        assert other[section] == nano[section]
    assert {k: v for k, v in other["filter"].items() if k != "method"} == {
        k: v for k, v in nano["filter"].items() if k != "method"
    }
