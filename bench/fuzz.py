"""Coverage-guided fuzzing of every reader and the run behind it (atheris; outside CI).

    .venv/bin/pip install atheris
    .venv/bin/python bench/fuzz.py -atheris_runs=20000 [-max_total_time=1800]

Each input's first byte picks a container (Carmen text, Player text, ROS 1 bag, ROS 2 db3 bag,
ROS 2 mcap bag, plain MCAP); the rest is the file, which ``dynslam process --max-scans 20``
reads. The seeds are a short simulated run in each container and the bundled samples, so
the mutations start from well-formed files. Anything but exit 0 or exit 1 with one printable
line is a finding: atheris stops and writes the input as ``crash-<hash>``.
"""

from __future__ import annotations

import shutil
import sys
import tempfile
from pathlib import Path

import atheris
from click.testing import CliRunner

import dynslam_cli.job  # noqa: F401 - the run, and the readers it imports when it runs
import dynslam_formats.carmen
import dynslam_formats.mcap_plain
import dynslam_formats.player
import dynslam_formats.ros  # noqa: F401
from dynslam_cli.cli import main

ROOT = Path(__file__).resolve().parent.parent
# (container, the file's name (inside a folder for ROS 2 bags), its --format)
CONTAINERS = [("carmen", "log.clf", "carmen"), ("player", "log.player", "player"),
              ("rosbag1", "log.bag", "ros"), ("rosbag2", "bag/bag_0.db3", "ros"),
              ("rosbag2-mcap", "bag/bag_0.mcap", "ros"), ("mcap", "log.mcap", "mcap")]
WORK = Path(tempfile.mkdtemp(prefix="dynslam-fuzz-"))
METADATA: dict[str, bytes] = {}  # a bag folder's metadata.yaml, from the seed run


def seeds(corpus: Path) -> None:
    """Write one seed per container into ``corpus`` (prefixed with its selector byte)."""
    corpus.mkdir(parents=True, exist_ok=True)
    runner = CliRunner()
    for i, (fmt, _, _) in enumerate(CONTAINERS):
        if fmt in ("carmen", "player"):
            world = ROOT / "samples" / "hall" / "hall.log"
            if fmt == "carmen":
                data = b"".join(world.read_bytes().splitlines(keepends=True)[:120])
            else:
                data = PLAYER_SEED.encode()
        else:
            out = WORK / f"seed-{fmt}"
            r = runner.invoke(main, ["simulate", "crowd", "-o", str(out), "--duration", "1",
                                     "--format", fmt])
            assert r.exit_code == 0, r.output
            log = Path(r.stdout.strip())
            if log.is_dir():
                METADATA[fmt] = (log / "metadata.yaml").read_bytes()
                log = next(p for p in log.iterdir() if p.name != "metadata.yaml")
            data = log.read_bytes()
        (corpus / f"seed-{fmt}").write_bytes(bytes([i]) + data)


PLAYER_SEED = "## File version 0.3.0\n" + "".join(
    f"{t}.0 host 6665 position2d 00 004 001 {0.1 * t:.1f} 0 0 0 0 0 0\n"
    f"{t}.0 host 6665 laser 00 001 001 0 -1.5708 1.5708 0.0175 8.0 181 "
    + " ".join("2.0 0" for _ in range(181)) + "\n" for t in range(1, 6))


def metadata(fmt: str) -> bytes:
    if fmt not in METADATA:
        seeds(WORK / "corpus-metadata")
    return METADATA[fmt]


def one_input(data: bytes) -> None:
    if not data:
        return
    fmt, name, format_name = CONTAINERS[data[0] % len(CONTAINERS)]
    case = WORK / "case"
    shutil.rmtree(case, ignore_errors=True)
    path = case / name
    path.parent.mkdir(parents=True)
    path.write_bytes(data[1:])
    log = path
    if "/" in name:  # a ROS 2 bag: the folder with its metadata.yaml
        (path.parent / "metadata.yaml").write_bytes(metadata(fmt))
        log = path.parent
    r = CliRunner().invoke(main, ["process", str(log), "-o", str(case / "out"), "-q",
                                  "--max-scans", "20", "--format", format_name],
                           catch_exceptions=False)
    if r.exit_code not in (0, 1):
        raise RuntimeError(f"exit {r.exit_code}: {r.stderr}")
    if r.exit_code == 1 and not (r.stderr.startswith("dynslam: error: ")
                                 and r.stderr.count("\n") == 1
                                 and r.stderr[:-1].isprintable()):
        raise RuntimeError(f"not one printable line: {r.stderr!r}")
    if "Traceback" in r.stderr:
        raise RuntimeError(r.stderr)
    leftovers = [p.name for p in case.iterdir() if p.name.startswith(".")]
    if leftovers:
        raise RuntimeError(f"left behind: {leftovers}")


if __name__ == "__main__":
    corpus = WORK / "corpus"
    seeds(corpus)  # (which imports the rest: rosbags' and mcap's readers and writers)
    atheris.instrument_all()  # coverage of every loaded Python function
    atheris.Setup([sys.argv[0], *sys.argv[1:], str(corpus)], one_input)
    atheris.Fuzz()
