"""The configuration reference, generated from the config dataclasses.

One generator serves the documentation's config reference page (:func:`reference_markdown`) and
``nanoslam config`` (:func:`annotated_yaml`). Both walk :class:`~nanoslam_jax.app.config.Config` and
its sections with :func:`dataclasses.fields`, so a section or key added to ``_config_schema.py`` appears
in both without further work, with the type, default, range, staticness and ``doc=`` string it
was declared with.
"""

from __future__ import annotations

import dataclasses
import typing
from typing import Any, NamedTuple

import yaml

from nanoslam_jax.app.config import Config, config_to_dict, type_name

__all__ = ["KeyDoc", "SectionDoc", "config_sections", "annotated_yaml", "reference_markdown"]


class KeyDoc(NamedTuple):
    """One config key.

    Attributes:
        key: the dotted key, e.g. ``filter.gate``.
        type: what values it takes, in words (``'a number'``, ``"one of 'a', 'b'"``, ...).
        default: its default value.
        range: the allowed range, e.g. ``'> 0'`` or ``'[0, 1]'`` (``''`` when unbounded).
        static: whether it changes the compiled program (shapes, branches) rather than being a
            traced hyperparameter that sweeps vary without recompiling.
        doc: what it means.
    """

    key: str
    type: str
    default: Any
    range: str
    static: bool
    doc: str


class SectionDoc(NamedTuple):
    """A config section (``''`` for the top-level keys) and its keys.

    Attributes:
        name: the section's key (``''`` for the top level).
        doc: the section dataclass's docstring summary.
        keys: its keys in declaration order.
    """

    name: str
    doc: str
    keys: tuple[KeyDoc, ...]


def _range(meta: Any) -> str:
    lo, hi, lo_open = meta.get("lo"), meta.get("hi"), meta.get("lo_open")
    if lo is not None and hi is not None:
        return f"{'(' if lo_open else '['}{lo:g}, {hi:g}]"
    if lo is not None:
        return f"{'>' if lo_open else '>='} {lo:g}"
    if hi is not None:
        return f"<= {hi:g}"
    return ""


def _summary(cls: type) -> str:
    return " ".join((cls.__doc__ or "").strip().split("\n\n")[0].split())


def config_sections(cls: type = Config) -> tuple[SectionDoc, ...]:
    """Every section of ``cls`` and every key of each, walking the dataclasses.

    Args:
        cls: the root dataclass (default: :class:`~nanoslam_jax.app.config.Config`).
    """
    hints = typing.get_type_hints(cls)
    default = cls()
    top, sections = [], []
    for f in dataclasses.fields(cls):
        tp = hints[f.name]
        if isinstance(tp, type) and dataclasses.is_dataclass(tp):
            sub_hints = typing.get_type_hints(tp)
            sub_default = getattr(default, f.name)
            keys = tuple(
                KeyDoc(
                    f"{f.name}.{g.name}",
                    type_name(sub_hints[g.name]),
                    getattr(sub_default, g.name),
                    _range(g.metadata),
                    bool(g.metadata.get("static")),
                    g.metadata.get("doc", ""),
                )
                for g in dataclasses.fields(tp)
            )
            sections.append(SectionDoc(f.name, _summary(tp), keys))
        else:
            top.append(
                KeyDoc(
                    f.name,
                    type_name(tp),
                    getattr(default, f.name),
                    _range(f.metadata),
                    bool(f.metadata.get("static")),
                    f.metadata.get("doc", ""),
                )
            )
    return (SectionDoc("", _summary(cls), tuple(top)), *sections)


def _yaml_value(v: Any) -> str:
    return yaml.safe_dump(v, default_flow_style=True, width=10_000).strip().removesuffix("\n...").strip()


def _details(k: KeyDoc) -> str:
    default = repr(k.default) if isinstance(k.default, str) else _yaml_value(k.default)
    parts = [k.type] + ([f"range {k.range}"] if k.range else [])
    parts += ["static: recompiles" if k.static else "traced: sweepable", f"default {default}"]
    return "[" + "; ".join(parts) + "]"


def annotated_yaml(cfg: Config, header: str = "") -> str:
    """``cfg`` as YAML with each key's doc, type, range, staticness and default as a comment.

    The text loads back (``yaml.safe_load`` then :func:`~nanoslam_jax.app.config.config_from_dict`)
    to ``cfg``; ``nanoslam config`` prints it.

    Args:
        cfg: the resolved configuration.
        header: comment lines put first (without ``#``).
    """
    values = config_to_dict(cfg)
    lines = [f"# {h}" if h else "#" for h in header.splitlines()]
    for sec in config_sections():
        indent = "  " if sec.name else ""
        if sec.name:
            lines += ["", f"# {sec.doc}", f"{sec.name}:"]
        node = values[sec.name] if sec.name else values
        for k in sec.keys:
            name = k.key.rsplit(".", 1)[-1]
            if k.doc:
                lines.append(f"{indent}# {k.doc}")
            lines.append(f"{indent}# {_details(k)}")
            lines.append(f"{indent}{name}: {_yaml_value(node[name])}")
    return "\n".join(lines) + "\n"


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def reference_markdown(heading_level: int = 2) -> str:
    """The config reference as Markdown: one table per section (key, type, default, range,
    static, doc). The documentation's config reference page is this text.

    Args:
        heading_level: Markdown heading level of each section's title.
    """
    hashes = "#" * heading_level
    out = []
    for sec in config_sections():
        title = f"`{sec.name}`" if sec.name else "Top level"
        out += [
            f"{hashes} {title}",
            "",
            sec.doc,
            "",
            "| key | type | default | range | static | meaning |",
            "|---|---|---|---|---|---|",
        ]
        for k in sec.keys:
            out.append(
                f"| `{k.key}` | {_cell(k.type)} | `{_cell(_yaml_value(k.default))}` | {_cell(k.range)} | "
                f"{'yes' if k.static else 'no'} | {_cell(k.doc)} |"
            )
        out.append("")
    return "\n".join(out)
