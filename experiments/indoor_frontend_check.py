"""The raw laser front end on simulated indoor scans against their truth (docs/simulate_indoor.md).

    .venv/bin/python experiments/indoor_frontend_check.py [--seeds 0-15] [--duration 60] [--every 10]
        [--set indoor.key=value ...] [--set detector.key=value ...]

For every seed an indoor log (:func:`nanoslam_jax.sim.indoor.simulate_indoor`, the ``indoor`` section
with the overrides) is simulated; every ``--every``-th scan goes through
:func:`nanoslam_jax.frontend.extract_features` (the ``detector`` section) and its features are compared with
the truth, in the world frame through the true laser pose of the scan:

* lines: each line segment against the wall most of its beams returned from (``beam_truth``), its ``(rho,
  alpha)`` against the wall's line in the laser frame; segments with beams on two walls (a corner's return
  shared by both segments) counted apart;
* corners: distance of each corner point to the nearest truth corner;
* arcs: circles within 0.2 m of a pillar, centre and radius errors; circles elsewhere counted;
* break points: those the front end calls an object's end (a farther return or none beyond), the share
  within 5 cm of a truth break point (door jambs, partition ends) and the distance of those, and the share
  within 5 cm of a truth break point or corner (a wall seen up to a corner that juts out ends there).

Prints one Markdown table per template and pooled: medians and 90th percentiles over all features.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time

import numpy as np

from _seeds import format_seeds, parse_seeds

from nanoslam_jax.app.config import ConfigError, load_config
from nanoslam_jax.frontend import extract_features
from nanoslam_jax.frontend._types import EDGE_FARTHER, EDGE_NO_RETURN
from nanoslam_jax.sim.indoor import hessian_lines, simulate_indoor
from nanoslam_jax.sim.laser import KIND_WALL
import jax

jax.config.update("jax_enable_x64", True)  # the library computes in float64


def _world(pose: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    return np.stack([pose[:, 0] + c * x - s * y, pose[:, 1] + s * x + c * y], axis=1)


def _nearest(p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    if p.shape[0] == 0 or q.shape[0] == 0:
        return np.full(p.shape[0], np.inf), np.zeros(p.shape[0], dtype=int)
    d = np.hypot(p[:, None, 0] - q[None, :, 0], p[:, None, 1] - q[None, :, 1])
    return d.min(axis=1), d.argmin(axis=1)


def check(log, detector, every: int) -> dict[str, np.ndarray]:
    """The front end's errors on every ``every``-th scan of ``log``."""
    pick = np.arange(0, log.scans.n_scans, every)
    scans, pose, w = log.scans.select(pick), log.scan_pose[pick], log.world
    f = extract_features(scans, detector)
    out: dict[str, list] = {
        k: []
        for k in (
            "rho",
            "alpha",
            "rho_shared",
            "alpha_shared",
            "corner",
            "centre",
            "radius",
            "stray_arcs",
            "break_near",
            "break_err",
            "break_or_corner",
        )
    }
    rho, alpha = hessian_lines(w.walls)
    ln = f.lines
    for q in range(ln.scan.size):
        j, k = int(ln.scan[q]), int(pick[ln.scan[q]])
        beams = slice(int(ln.first_beam[q]), int(ln.last_beam[q]) + 1)
        ids = log.object_id[k, beams][log.kind[k, beams] == KIND_WALL]
        if ids.size == 0:
            continue
        wall = np.bincount(ids).argmax()
        p = pose[j]
        r = rho[wall] - (p[0] * np.cos(alpha[wall]) + p[1] * np.sin(alpha[wall]))
        a = alpha[wall] - p[2] + (np.pi if r < 0 else 0.0)
        d_rho = abs(ln.rho[q] - abs(r))
        d_alpha = abs(np.angle(np.exp(1j * (ln.alpha[q] - a))))
        shared = np.unique(w.wall_line[ids]).size > 1
        out["rho_shared" if shared else "rho"].append(d_rho)
        out["alpha_shared" if shared else "alpha"].append(np.degrees(d_alpha))
    out["corner"] = list(_nearest(_world(pose[f.corners.scan], f.corners.x, f.corners.y), w.corners)[0])
    c = f.circles
    d, i = _nearest(_world(pose[c.scan], c.cx, c.cy), w.pillars[:, :2])
    on = d < 0.2
    out["centre"], out["radius"] = list(d[on]), list(np.abs(c.radius[on] - w.pillars[i[on], 2]))
    out["stray_arcs"] = [int((~on).sum())]
    b = f.breakpoints
    end = (b.beyond == EDGE_FARTHER) | (b.beyond == EDGE_NO_RETURN)
    d, _ = _nearest(_world(pose[b.scan[end]], b.x[end], b.y[end]), w.breakpoints)
    out["break_near"], out["break_err"] = list(d < 0.05), list(d[d < 0.05])
    d_any, _ = _nearest(_world(pose[b.scan[end]], b.x[end], b.y[end]), np.concatenate([w.breakpoints, w.corners]))
    out["break_or_corner"] = list(d_any < 0.05)
    res = {k: np.asarray(v, dtype=float) for k, v in out.items()}
    res["scans"] = np.array([pick.size])
    return res


def _stat(v: np.ndarray, scale: float = 1.0, digits: int = 2) -> str:
    if v.size == 0:
        return "-"
    return f"{scale * np.median(v):.{digits}f} / {scale * np.percentile(v, 90):.{digits}f}"


def table(rows: dict[str, list[dict[str, np.ndarray]]]) -> str:
    head = (
        "| template | logs | scans | lines on one wall | rho error (mm), median / 90 % | alpha error (deg) | "
        "lines over a corner | their rho error (mm) | corners | corner error (cm) | arcs on a pillar | "
        "centre error (cm) | radius error (cm) | other arcs | object ends | within 5 cm of a truth break point "
        "| their error (cm) | within 5 cm of a truth break point or corner |"
    )
    lines = [head, "|---|" + "---:|" * 17]
    for name, rs in rows.items():
        cat = {k: np.concatenate([r[k] for r in rs]) for k in rs[0]}
        lines.append(
            f"| {name} | {len(rs)} | {int(cat['scans'].sum())} | {cat['rho'].size} | {_stat(cat['rho'], 1000)} | "
            f"{_stat(cat['alpha'], 1, 3)} | {cat['rho_shared'].size} | {_stat(cat['rho_shared'], 1000)} | "
            f"{cat['corner'].size} | {_stat(cat['corner'], 100)} | {cat['centre'].size} | {_stat(cat['centre'], 100)} | "
            f"{_stat(cat['radius'], 100)} | {int(cat['stray_arcs'].sum())} | {cat['break_near'].size} | "
            f"{cat['break_near'].mean() if cat['break_near'].size else float('nan'):.2f} | "
            f"{_stat(cat['break_err'], 100)} | "
            f"{cat['break_or_corner'].mean() if cat['break_or_corner'].size else float('nan'):.2f} |"
        )
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=parse_seeds, default="0-15", help="indoor.seed values, e.g. 0-15 or 1,4,9")
    p.add_argument("--duration", type=float, default=60.0, help="seconds per log (indoor.duration)")
    p.add_argument("--every", type=int, default=10, help="check every n-th scan")
    p.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override an indoor.* or detector.* key (repeatable)",
    )
    args = p.parse_args(argv)
    try:
        cfg = load_config(None, args.overrides)
    except ConfigError as e:
        print(f"indoor_frontend_check: {e}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    rows: dict[str, list] = {}
    for seed in args.seeds:
        ind = dataclasses.replace(cfg.indoor, seed=seed, duration=args.duration)
        log = simulate_indoor(ind)
        r = check(log, cfg.detector, args.every)
        rows.setdefault(log.world.template, []).append(r)
        rows.setdefault("all", []).append(r)
    rows = {k: rows[k] for k in sorted(rows, key=lambda k: (k == "all", k))}
    sets = " ".join(f"--set {o}" for o in args.overrides)
    print(
        f"indoor_frontend_check.py --seeds {format_seeds(args.seeds)} --duration {args.duration:g} --every {args.every} {sets}".rstrip()
        + f" ({time.perf_counter() - t0:.0f} s)\n"
    )
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
