"""Draw indoor worlds with their truth and one scan (docs/figures/indoor_templates.png).

    .venv/bin/python experiments/indoor_figure.py [--seeds 1,3,0] [--out docs/figures/indoor_templates.png]
        [--set indoor.key=value ...]

One panel per seed (each drawn with its template: by default a room, an L-room and a corridor): the walls
(each line in its own colour, partitions dashed), the pillars, the truth corners and break points, the
desired path of the reference point, and the returns of the scan 20 s into the log with the laser's
pose.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from nanoslam_jax.app.config import load_config  # noqa: E402
from nanoslam_jax.sim.indoor import BREAK_DOOR, simulate_indoor  # noqa: E402
import jax

jax.config.update("jax_enable_x64", True)  # the library computes in float64


def draw(ax, log, t_scan: float) -> None:
    """One world: walls, pillars, corners, break points, path and the returns of the scan at ``t_scan``."""
    w = log.world
    parts = set(w.breakpoint_wall[w.breakpoint_kind != BREAK_DOOR].tolist())
    for i, (x0, y0, x1, y1) in enumerate(w.walls):
        ax.plot([x0, x1], [y0, y1], color=plt.cm.tab10(w.wall_line[i] % 10), lw=2.5, ls="--" if i in parts else "-")
    for xc, yc, r in w.pillars:
        ax.add_patch(plt.Circle((xc, yc), r, fill=False, color="k", lw=2))
    ax.plot(*w.corners.T, "s", mfc="none", mec="k", ms=8, label="corner")
    door = w.breakpoint_kind == BREAK_DOOR
    ax.plot(*w.breakpoints[door].T, "^", color="C3", ms=7, label="break point (door)")
    ax.plot(*w.breakpoints[~door].T, "v", color="C1", ms=7, label="break point (free end)")
    track, _, _ = log.path.at(np.linspace(0.0, log.path.total, 2000))
    ax.plot(*track.T, ":", color="0.4", lw=1, label="desired path")
    k = int(np.argmin(np.abs(log.scans.time - t_scan)))
    p, r = log.scan_pose[k], log.scans.ranges[k]
    ok = log.scans.valid[k]
    th = p[2] + log.scans.angles[ok]
    ax.plot(p[0] + r[ok] * np.cos(th), p[1] + r[ok] * np.sin(th), ".", color="C2", ms=2, label="scan returns")
    ax.plot(*p[:2], "o", color="C2", ms=6)
    ax.arrow(p[0], p[1], 0.6 * np.cos(p[2]), 0.6 * np.sin(p[2]), width=0.05, color="C2")
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", default="1,3,0", help="indoor.seed of each panel")
    p.add_argument("--out", default="docs/figures/indoor_templates.png")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = p.parse_args(argv)
    cfg = load_config(None, args.overrides)
    seeds = [int(s) for s in args.seeds.split(",")]
    fig, axes = plt.subplots(1, len(seeds), figsize=(6 * len(seeds), 6))
    for ax, seed in zip(np.atleast_1d(axes), seeds):
        log = simulate_indoor(dataclasses.replace(cfg.indoor, seed=seed, duration=25.0))
        draw(ax, log, 20.0)
        ax.set_title(f"{log.world.template} (indoor.seed {seed})")
    handles, labels = np.atleast_1d(axes)[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=9)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    fig.savefig(args.out, dpi=110)
    print(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
