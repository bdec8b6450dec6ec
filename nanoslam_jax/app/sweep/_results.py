"""Results of a sweep on disk: the atomic ``results.csv`` appender and reader, the per-configuration
summary over seeds (median, interquartile range and range, failed seeds counted under the rule of
:mod:`nanoslam_jax.eval._scoring`), and the best configuration as a YAML file."""

from __future__ import annotations

import contextlib
import csv
import datetime as _dt
import io
import math
import os
from pathlib import Path
from typing import Any, Iterable, Optional, Sequence

import numpy as np
import yaml

from nanoslam_jax.eval._scoring import summarize_runs
from nanoslam_jax._version import __version__
from nanoslam_jax.app.config import config_to_dict
from nanoslam_jax.app.sweep._spec import ConfigPoint, SweepSpec

__all__ = [
    "ResultsFile",
    "read_results",
    "format_value",
    "summarize",
    "write_summary",
    "select_best",
    "write_best_yaml",
    "TIMING_COLUMNS",
]

#: Columns that hold wall-clock times (they differ between otherwise identical runs).
TIMING_COLUMNS = ("run_s", "compile_s")


def format_value(v: Any) -> str:
    """A CSV cell: floats with ``repr`` (exact round trip), booleans as true/false, None as empty."""
    if v is None:
        return ""
    if isinstance(v, (bool, np.bool_)):
        return "true" if v else "false"
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    return str(v)


@contextlib.contextmanager
def _locked(lock_path: Path):
    """An exclusive advisory lock on ``lock_path`` (POSIX ``flock``; no-op where unavailable)."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    fd = os.open(lock_path, os.O_CREAT | os.O_RDWR, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)


def _complete_prefix(data: bytes, n_columns: int) -> int:
    """Length of the longest prefix of ``data`` made of complete CSV records of ``n_columns`` cells.

    A record is complete when it ends with a newline and parses into ``n_columns`` cells; an
    interrupted append leaves at most one incomplete record at the end, which is cut off.
    """
    if not data:
        return 0
    end = data.rfind(b"\n") + 1
    while end > 0:
        text = data[:end].decode("utf-8", errors="replace")
        rows = list(csv.reader(io.StringIO(text, newline="")))
        if rows and all(len(r) == n_columns for r in rows):
            return end
        end = data.rfind(b"\n", 0, end - 1) + 1
    return 0


class ResultsFile:
    """``results.csv``: a header and one row per finished run, appended one batch at a time.

    Each append is one ``write`` of the whole batch's rows to a file opened with ``O_APPEND``,
    under an exclusive lock file, followed by ``fsync``: a batch's rows are on disk entirely
    or (after a crash in the middle of the write) as a cut-off last record, which the reader
    and the next append discard. The header is written through a temporary file and a rename.

    Args:
        path: the CSV file.
        columns: the column names (the header).
    """

    def __init__(self, path: str | os.PathLike, columns: Sequence[str]):
        self.path = Path(path)
        self.columns = list(columns)
        self.lock = self.path.with_name(self.path.name + ".lock")

    def create(self) -> None:
        """Write the header (atomically); the file must not exist yet."""
        tmp = self.path.with_name(self.path.name + ".tmp")
        buf = io.StringIO(newline="")
        csv.writer(buf, lineterminator="\n").writerow(self.columns)
        with open(tmp, "w", newline="") as f:
            f.write(buf.getvalue())
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, self.path)

    def check_header(self) -> None:
        """Raise ``ValueError`` unless the file's header equals ``columns``."""
        with open(self.path, newline="") as f:
            header = next(csv.reader(f), None)
        if header != self.columns:
            raise ValueError(f"{self.path}: its columns differ from this sweep's; it was written by another sweep")

    def repair(self) -> int:
        """Cut a trailing incomplete record (left by a killed append); returns the bytes removed."""
        with _locked(self.lock):
            data = self.path.read_bytes()
            keep = _complete_prefix(data, len(self.columns))
            if keep < len(data):
                with open(self.path, "r+b") as f:
                    f.truncate(keep)
                    f.flush()
                    os.fsync(f.fileno())
            return len(data) - keep

    def append(self, rows: Iterable[dict]) -> None:
        """Append rows (mappings column -> value; missing columns are left empty) in one write."""
        buf = io.StringIO(newline="")
        w = csv.writer(buf, lineterminator="\n")
        for r in rows:
            w.writerow([format_value(r.get(c)) for c in self.columns])
        payload = buf.getvalue().encode("utf-8")
        if not payload:
            return
        with _locked(self.lock):
            fd = os.open(self.path, os.O_WRONLY | os.O_APPEND)
            try:
                view = memoryview(payload)
                while view:  # one write in practice; loop only on a short write
                    n = os.write(fd, view)
                    view = view[n:]
                os.fsync(fd)
            finally:
                os.close(fd)


def read_results(path: str | os.PathLike, key: str = "run_id") -> list[dict]:
    """The complete rows of a ``results.csv`` (strings, as written); a cut-off last record is ignored.

    When a ``key`` (the run id) appears more than once, the last row wins.
    """
    p = Path(path)
    if not p.is_file():
        return []
    data = p.read_bytes()
    first = data.split(b"\n", 1)[0].decode("utf-8")
    header = next(csv.reader([first]))
    keep = _complete_prefix(data, len(header))
    rows = list(csv.DictReader(io.StringIO(data[:keep].decode("utf-8"), newline="")))
    by_id = {}
    for r in rows:
        by_id[r[key]] = r
    return list(by_id.values())


def summarize(
    rows: Sequence[dict],
    points: Sequence[ConfigPoint],
    groups: dict[str, str],
    metric_keys: Sequence[str],
    goals: Optional[dict] = None,
) -> list[dict]:
    """One summary per configuration over its seeds (:func:`~nanoslam_jax.eval._scoring.summarize_runs`).

    Args:
        rows: result rows (as read from ``results.csv``).
        points: the sweep's configurations (for the swept values).
        groups: config id -> group label.
        metric_keys: metrics to summarise.
        goals: a metric's goal (``'min'``/``'max'``) where it differs from
            :func:`~nanoslam_jax.eval._scoring.metric_goal`'s (the sweep's ``metric`` and ``goal``).

    Returns:
        Per configuration (in id order, only those with rows): ``config_id``, ``group``, the swept
        values, ``n_runs``, ``n_ok``, ``n_failed``, ``failed_seeds``, ``reasons`` (distinct failure
        reasons), and ``<metric>_median``, ``<metric>_q1``, ``<metric>_q3``, ``<metric>_min`` and
        ``<metric>_max`` over every seed, a failed seed counting as the worst value (``inf`` for
        an error; a descriptive column such as ``n_landmarks`` over the seeds that finished ok).
    """
    by_cfg: dict[str, list[dict]] = {}
    for r in rows:
        by_cfg.setdefault(r["config_id"], []).append(r)
    out = []
    for p in points:
        rs = by_cfg.get(p.config_id)
        if not rs:
            continue
        st = summarize_runs(rs, metric_keys, goals)
        s: dict = {
            "config_id": p.config_id,
            "group": groups.get(p.config_id, ""),
            **p.values,
            "n_runs": st["n_runs"],
            "n_ok": st["n_ok"],
            "n_failed": st["n_failed"],
            "failed_seeds": st["failed_seeds"],
            "reasons": st["reasons"],
        }
        s.update({k: v for k, v in st.items() if k not in s})
        out.append(s)
    return out


def select_best(summary: Sequence[dict], metric: str, n_seeds: int, goal: str = "min") -> Optional[dict]:
    """The best configuration by the median of ``metric`` over seeds.

    Only configurations whose every seed finished ``ok`` compete; when none did, those with the
    most ``ok`` seeds do. Ties go to the lower configuration id. ``None`` when no configuration
    has a finite median.
    """
    cands = [s for s in summary if math.isfinite(s.get(f"{metric}_median", math.nan))]
    if not cands:
        return None
    full = [s for s in cands if s["n_ok"] >= n_seeds]
    if not full:
        most = max(s["n_ok"] for s in cands)
        full = [s for s in cands if s["n_ok"] == most]
    sign = 1.0 if goal == "min" else -1.0
    return min(full, key=lambda s: (sign * s[f"{metric}_median"], s["config_id"]))


def write_summary(
    out: Path,
    summary: Sequence[dict],
    spec: SweepSpec,
    metric_keys: Sequence[str],
    best: Optional[dict],
    complete: bool,
) -> None:
    """``summary.csv`` (every statistic) and ``summary.md`` (a readable table sorted by the metric)."""
    keys = list(spec.swept_keys)
    cols = ["config_id", "group", *keys, "n_runs", "n_ok", "n_failed", "failed_seeds"]
    cols += [f"{m}_{s}" for m in metric_keys for s in ("median", "q1", "q3", "min", "max")] + ["reasons"]
    tmp = out / "summary.csv.tmp"
    with open(tmp, "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(cols)
        for s in summary:
            w.writerow([format_value(s.get(c)) for c in cols])
    os.replace(tmp, out / "summary.csv")

    m = spec.metric
    sign = 1.0 if spec.goal == "min" else -1.0
    order = sorted(
        summary,
        key=lambda s: (
            not math.isfinite(s[f"{m}_median"]),
            sign * s[f"{m}_median"] if math.isfinite(s[f"{m}_median"]) else 0.0,
            s["config_id"],
        ),
    )
    shown = [k for k in (m, "rmse_fixed", "rmse_aligned", "final_error", "n_landmarks") if k in metric_keys]
    shown = list(dict.fromkeys(shown))
    lines = [
        f"# Sweep {spec.name}",
        "",
        f"{len(summary)} configurations x {len(spec.seeds)} seeds; median [q1, q3] (min-max) over the seeds, "
        f"a failed seed counting as the worst value (inf for an error); sorted by {m} "
        f"({'lower' if spec.goal == 'min' else 'higher'} is better)."
        + ("" if complete else " **Partial: the sweep has not finished.**"),
        "",
    ]
    if best is not None:
        lines += [
            f"Best: **{best['config_id']}** ({', '.join(f'{k}={best[k]!r}' for k in keys) or 'the base config'}), "
            f"{m} median {best[f'{m}_median']:.4g}; written to best.yaml.",
            "",
        ]
    head = ["config", "group", *keys, "ok/runs", *shown]
    lines.append("| " + " | ".join(head) + " |")
    lines.append("|" + "---|" * len(head))
    fmt = lambda v: f"{v:.4g}" if isinstance(v, float) else str(v)  # noqa: E731
    for s in order:
        cells = [s["config_id"], s["group"], *(fmt(s[k]) for k in keys), f"{s['n_ok']}/{s['n_runs']}"]
        cells += [
            f"{s[f'{k}_median']:.4g} [{s[f'{k}_q1']:.4g}, {s[f'{k}_q3']:.4g}] ({s[f'{k}_min']:.4g}-{s[f'{k}_max']:.4g})"
            for k in shown
        ]
        lines.append("| " + " | ".join(cells) + " |")
    failed = [s for s in summary if s["n_failed"]]
    if failed:
        lines += ["", "Failed runs:", ""]
        lines += [
            f"- {s['config_id']}: {s['n_failed']} of {s['n_runs']} (seeds {s['failed_seeds'].replace(';', ', ')}): "
            f"{s['reasons']}"
            for s in failed
        ]
    (out / "summary.md").write_text("\n".join(lines) + "\n")


def write_best_yaml(path: Path, spec: SweepSpec, point: ConfigPoint, best: dict) -> None:
    """The best configuration as a complete config file, loadable by ``nanoslam run``."""
    m = spec.metric
    d = config_to_dict(point.config)
    d["name"] = f"{spec.name}-best"
    values = ", ".join(f"{k}={v!r}" for k, v in point.values.items()) or "the base config"
    seg = (
        f"\n# The sweep used only the first {spec.segments} segments of the log; this file runs the whole log."
        if spec.segments
        else ""
    )
    header = (
        f"# Best configuration of sweep '{spec.name}' ({spec.source}), written by nanoslam-jax {__version__} "
        f"on {_dt.datetime.now().isoformat(timespec='seconds')}.\n"
        f"# {point.config_id}: {values}\n"
        f"# {m}: median {best[f'{m}_median']:.6g} [q1 {best[f'{m}_q1']:.6g}, q3 {best[f'{m}_q3']:.6g}] over "
        f"{best['n_ok']} of {best['n_runs']} seeds ({'lower' if spec.goal == 'min' else 'higher'} is better)."
        f"{seg}\n# Run it with: nanoslam run {path.name}\n"
    )
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(header + yaml.safe_dump(d, sort_keys=False))
    os.replace(tmp, path)
