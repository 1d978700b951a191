"""The output folder contract, written atomically.

Everything goes into a hidden temporary folder beside the target, which is renamed into place
only when complete: a failed or interrupted run leaves no half-written map behind.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from dynslam_cli.config import Config
from dynslam_cli.errors import OutputError
from dynslam_cli.pipeline import SlamResult
from formats.landmarks import write_landmarks
from formats.mapfile import write_map
from formats.picture import write_picture
from formats.tum import write_tum

OUTPUT_FILES = ("static.pgm", "static.yaml", "dynamic.pgm", "dynamic.yaml", "map.png",
                "landmarks.csv", "trajectory.tum", "summary.json")


def check_target(target: Path, force: bool) -> None:
    """Refuse an existing output folder unless ``force``."""
    if target.exists() and not force:
        raise OutputError(f"{target}: output folder exists; use --force to replace it")
    if target.exists() and not target.is_dir():
        raise OutputError(f"{target}: exists and is not a folder")


@contextmanager
def atomic_output_dir(target: Path, force: bool) -> Iterator[Path]:
    """Yield a temporary folder; on success it replaces ``target``, on failure it vanishes."""
    check_target(target, force)
    parent = target.absolute().parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".partial", dir=parent))
        umask = os.umask(0)
        os.umask(umask)
        tmp.chmod(0o777 & ~umask)  # mkdtemp makes it private; the result is an ordinary folder
    except OSError as e:
        raise OutputError(f"{target}: cannot create output folder: {e.strerror}") from None
    try:
        yield tmp
        check_target(target, force)
        if target.exists():
            trash = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=parent))
            os.replace(target, trash / target.name)
            os.replace(tmp, target)
            shutil.rmtree(trash, ignore_errors=True)
        else:
            os.replace(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def write_results(folder: Path, result: SlamResult, config: Config,
                  summary: dict[str, Any]) -> None:
    """Write every file of the output contract into ``folder``."""
    m = config.map
    write_map(folder, "static", result.static, m.free_threshold, m.occupied_threshold)
    write_map(folder, "dynamic", result.dynamic, m.free_threshold, m.occupied_threshold)
    write_picture(folder / "map.png", result.static, result.dynamic, result.trajectory,
                  result.landmarks, m.occupied_threshold)
    with open(folder / "landmarks.csv", "w", encoding="utf-8", newline="") as f:
        write_landmarks(f, result.landmarks)
    with open(folder / "trajectory.tum", "w", encoding="utf-8", newline="\n") as f:
        write_tum(f, result.trajectory)
    (folder / "summary.json").write_text(json.dumps(summary, indent=2, sort_keys=True) + "\n",
                                         encoding="utf-8")
