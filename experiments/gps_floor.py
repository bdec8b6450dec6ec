"""The GPS floor on the Victoria Park log: how much of the RMSE against GPS is the GPS's own error.

    python experiments/gps_floor.py                                   # the real log, paper setting
    python experiments/gps_floor.py configs/victoria_park_nano.yaml --json floor.json

Prints a Markdown report (nanoslam_jax.eval.gps_floor): GPS jumps and gaps, the short-term GPS error
against the dead-reckoning path fitted over short windows, the white noise, the fitted antenna
offset and clock shift, and what the fixed frame's rotation uncertainty costs at the track's
distances; then the floors of rmse_aligned and rmse_fixed.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

from nanoslam_jax.app.config import load_config
from nanoslam_jax.app.experiment import load_log
from nanoslam_jax.eval.gps_floor import floor_markdown, gps_floor_of_log
from nanoslam_jax.app._models import motion_model_from_config
import jax

jax.config.update("jax_enable_x64", True)  # the library computes in float64

DEFAULT = Path(__file__).resolve().parents[1] / "configs" / "victoria_park_nano.yaml"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("config", nargs="?", default=str(DEFAULT), help="config (vehicle constants, metrics section)")
    p.add_argument("--data", help="log directory (overrides data.path and $NANOSLAM_DATA)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument("--json", help="also write the figures here")
    args = p.parse_args()
    cfg = load_config(args.config, args.overrides)
    log = load_log(cfg, args.data)
    if log.frame != "relative":
        raise SystemExit(f"{log.source}: a simulated log's GPS is its ground truth; there is no floor to estimate")
    floor = gps_floor_of_log(motion_model_from_config(cfg), cfg.metrics, log)
    print(floor_markdown(floor))
    if args.json:
        Path(args.json).write_text(json.dumps(dataclasses.asdict(floor), indent=2) + "\n")


if __name__ == "__main__":
    main()
