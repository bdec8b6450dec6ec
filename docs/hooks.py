"""MkDocs hooks: pages generated from the code and from measurement files, so they cannot drift.

* ``<!-- nanoslam:config-reference -->`` becomes the config reference generated from the config
  dataclasses (:func:`nanoslam_jax.app.config_reference.reference_markdown`, the generator behind
  ``nanoslam config``).
* The package's docstrings use Sphinx roles (``:func:`run_filter```), which Markdown renders as
  text: ``on_page_content`` drops the role and keeps the code, shortened as ``~`` asks.
* ``<!-- nanoslam:benchmark -->`` and ``<!-- nanoslam:second-run -->`` become the benchmark table
  and the second-run table of ``docs/data/benchmark.json``, written by
  ``python experiments/benchmark.py --json docs/data/benchmark.json`` and formatted by that
  script's own ``markdown()``.
"""

from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _benchmark_markdown(part: str) -> str:
    """The ``part`` (``'rows'`` or ``'second_run'``) of the benchmark result as Markdown."""
    spec = importlib.util.spec_from_file_location("nanoslam_benchmark", ROOT / "experiments" / "benchmark.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    result = json.loads((ROOT / "docs" / "data" / "benchmark.json").read_text())
    head = (
        f"Commit `{result['commit']}`, {result['date']}, {result['cores']} cores, produced by "
        f"`{result['command']}` (the file `docs/data/benchmark.json`)."
    )
    return head + "\n\n" + bench.markdown({part: result[part]})


def on_page_markdown(markdown: str, page, config, files) -> str:
    if "<!-- nanoslam:config-reference -->" in markdown:
        from nanoslam_jax.app.config_reference import reference_markdown

        markdown = markdown.replace("<!-- nanoslam:config-reference -->", reference_markdown(heading_level=2))
    for marker, part in (("<!-- nanoslam:benchmark -->", "rows"), ("<!-- nanoslam:second-run -->", "second_run")):
        if marker in markdown:
            markdown = markdown.replace(marker, _benchmark_markdown(part))
    return markdown


_ROLE = re.compile(r":(?:func|class|meth|mod|attr|data|obj|exc|const):<code>(~?)([^<]*)</code>")


def _code(m: re.Match) -> str:
    name = m.group(2).rsplit(".", 1)[-1] if m.group(1) else m.group(2)
    return f"<code>{name}</code>"


def on_page_content(html: str, page, config, files) -> str:
    return _ROLE.sub(_code, html)
