"""The config reference and ``nanoslam config``.

The expected keys come from walking the config dataclasses here (``dataclasses.fields`` and the
field metadata), independently of the generator in ``nanoslam_jax.app.config_reference``: every key
must be in the reference with its type, default, range and doc, and ``nanoslam config`` must print
every key of each shipped config with its doc, as YAML that loads back to the resolved config.
"""

import dataclasses
import typing

import pytest
import yaml

from nanoslam_jax import __version__
from nanoslam_jax.app.cli import main
from nanoslam_jax.app.config import Config, config_from_dict, load_config
from nanoslam_jax.app.config_reference import reference_markdown
from tests.helpers.paths import REPO_ROOT

ROOT = REPO_ROOT
#: The run configs (a compare spec has ``methods``, a sweep spec ``grid`` or ``random``).
RUN_CONFIGS = sorted(
    p
    for p in (ROOT / "configs").glob("*.yaml")
    if not {"methods", "grid", "random"} & set(yaml.safe_load(p.read_text()) or {})
)


def _leaves(cls=Config, prefix=""):
    """(dotted key, dataclass field, annotation) of every leaf key, walking the dataclasses."""
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if dataclasses.is_dataclass(hints[f.name]):
            yield from _leaves(hints[f.name], f"{prefix}{f.name}.")
        else:
            yield f"{prefix}{f.name}", f, hints[f.name]


LEAVES = list(_leaves())


def _default(cfg, dotted):
    for part in dotted.split("."):
        cfg = getattr(cfg, part)
    return cfg


def test_the_walk_finds_every_section():
    sections = {k.split(".")[0] for k, _, _ in LEAVES if "." in k}
    assert {"data", "vehicle", "noise", "filter", "nano", "iterated", "metrics", "sim", "output"} <= sections
    assert len(LEAVES) > 60


@pytest.mark.parametrize("key", [k for k, _, _ in LEAVES])
def test_every_key_has_a_doc_string(key):
    field = {k: f for k, f, _ in LEAVES}[key]
    assert field.metadata.get("doc", "").strip(), f"{key} has no doc= in _config_schema.py"


def test_reference_lists_every_key_with_type_default_range_and_doc():
    rows = {}
    for line in reference_markdown().splitlines():
        if line.startswith("| `"):
            cells = [c.strip() for c in line.strip("|").split(" | ")]
            rows[cells[0].strip("`")] = cells
    assert set(rows) == {k for k, _, _ in LEAVES}
    default = Config()
    for key, field, tp in LEAVES:
        _, typ, dflt, rng, static, doc = rows[key]
        assert doc == field.metadata["doc"].replace("|", "\\|")
        assert static == ("yes" if field.metadata.get("static") else "no")
        value = _default(default, key)
        assert yaml.safe_load(dflt.strip("`")) == value, key
        if typing.get_origin(tp) is typing.Literal:
            assert all(repr(a) in typ for a in typing.get_args(tp)), (key, typ)
        lo, hi = field.metadata.get("lo"), field.metadata.get("hi")
        for bound in (lo, hi):
            if bound is not None:
                assert f"{bound:g}" in rng, (key, rng)
        if lo is None and hi is None:
            assert rng == ""


def _config_output(capsys, *argv):
    capsys.readouterr()
    assert main(["config", *map(str, argv)]) == 0
    return capsys.readouterr().out


@pytest.mark.parametrize("path", RUN_CONFIGS + [None], ids=lambda p: p.name if p else "embedded-default")
def test_nanoslam_config_prints_every_key_documented_and_loads_back(capsys, path):
    out = _config_output(capsys, *([path] if path else []))
    expected = load_config(path)
    assert config_from_dict(yaml.safe_load(out)) == expected
    assert __version__ in out.splitlines()[0]
    lines = out.splitlines()
    for key, field, _ in LEAVES:
        name = key.rsplit(".", 1)[-1]
        indent = "  " if "." in key else ""
        section = key.split(".")[0] if "." in key else None
        start = lines.index(f"{section}:") if section else 0
        at = next(i for i in range(start, len(lines)) if lines[i].startswith(f"{indent}{name}: "))
        comments = []
        i = at - 1
        while lines[i].startswith(f"{indent}#"):
            comments.append(lines[i])
            i -= 1
        text = " ".join(comments)
        assert field.metadata["doc"] in text, key
        assert ("static" if field.metadata.get("static") else "traced") in text, key


def test_nanoslam_config_shows_overrides_and_rejects_bad_ones(capsys):
    out = _config_output(capsys, ROOT / "configs" / "victoria_park_nano.yaml", "--set", "filter.gate=4.5")
    assert yaml.safe_load(out)["filter"]["gate"] == 4.5
    assert "--set filter.gate=4.5" in out.splitlines()[0]
    assert main(["config", "--set", "filter.gate=-1"]) == 2
    err = capsys.readouterr().err
    assert "filter.gate" in err and "Traceback" not in err


def test_version_flag(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"nanoslam-jax {__version__}"
