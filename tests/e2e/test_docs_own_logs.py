"""The complete example of docs/own-logs.md: its Python writes a ROS 2 bag from a simulated indoor
log, and its command runs SLAM on that bag, exactly as a user copies them from the page."""

from __future__ import annotations

import json
import re
import shlex
import subprocess
import sys

import pytest
from tests.helpers.paths import REPO_ROOT

ROOT = REPO_ROOT
PAGE = ROOT / "docs" / "own-logs.md"


def _blocks(kind: str) -> list[str]:
    return re.findall(rf"```{kind}\n(.*?)```", PAGE.read_text(), flags=re.S)


@pytest.mark.slow
def test_the_bag_example_writes_a_bag_and_runs_on_it(tmp_path):
    writer = [b for b in _blocks("python") if "Writer(" in b]
    assert len(writer) == 1, "one Python block of docs/own-logs.md writes the bag"
    command = [b for b in _blocks("bash") if "data.format=rosbag" in b]
    assert len(command) == 1, "one command of docs/own-logs.md runs on the bag"
    proc = subprocess.run([sys.executable, "-c", writer[0]], cwd=tmp_path, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert (tmp_path / "sim_bag" / "metadata.yaml").is_file()
    argv = shlex.split(command[0].replace("\\\n", " "))
    assert argv[:2] == ["nanoslam", "run"]
    argv = [a.replace("configs/", str(ROOT / "configs") + "/") for a in argv[2:]]
    proc = subprocess.run(
        [sys.executable, "-m", "nanoslam_jax.app.cli", "run", *argv, "--out", "out", "--quiet"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    m = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert m["finite"] and m["n_confirmed"] >= 4  # the room's walls were mapped
