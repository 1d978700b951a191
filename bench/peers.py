"""The peers beside dynslam: Karto and GMapping (built by ../shared/peers/build.sh) run on
the same logs and scored the same way, so a dynslam row is read beside them.

On bench/radish.py's rows (the Radish logs at the same odometry levels and seed; ATE after
SE(2) alignment, scan by scan):

    python bench/peers.py [--levels perfect,moderate,harsh] [--logs intel,aces] [--seed 0]
                          [--peers karto,gmapping] [--bin /tmp/peers/bin] [--out FILE.json]

On the raw Carmen logs of the Kümmerle et al. (2009) benchmark, scored by their relations
as bench/relations.py scores dynslam (``dynslam evaluate --relations``: mean absolute
translation m / rotation deg); Karto with its loop closing ("full") and without it
("local": its scan matching alone), GMapping as it is:

    python bench/peers.py --benchmark mit,intel,fr079 [--peers karto,gmapping] [--out FILE]

A peer that crashes or takes longer than --timeout seconds on a row is reported as such.
"""

from __future__ import annotations

import argparse
import gzip
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))
sys.path.insert(0, str(ROOT))

from radish import LEVELS, ate, poses, prepared, radish_logs  # noqa: E402
from relations import DATA, DYNSLAM, LOGS  # noqa: E402

from dynslam_formats.tum import read_tum  # noqa: E402

PEER_TUM = ROOT.parent / "shared" / "peers" / "peer_tum.py"
MODES = {"karto": ("full", "local"), "gmapping": ("full",)}
"""What each peer is run as on the benchmark logs: Karto's local SLAM is its driver with
``-loopClosing 0``; GMapping has no such switch."""


def run_peer(peer: str, log: Path, flags: list[str], bin_dir: Path, timeout: float,
             into: Path) -> tuple[Path | None, dict]:
    """The peer's driver on ``log`` (a Carmen log, plain or gzipped) with ``flags``: its
    trajectory as TUM (one pose per scan, by the peers' own peer_tum.py) in ``into``, or
    None, and the row's wall time or error."""
    plain = into / "log.txt"  # the drivers read a plain Carmen log
    if log.suffix == ".gz":
        with gzip.open(log, "rb") as src, open(plain, "wb") as dst:
            shutil.copyfileobj(src, dst)
    else:
        plain = log
    out, tum = into / "peer.out", into / "peer.tum"
    start = time.perf_counter()
    try:
        with open(out, "w") as f:
            run = subprocess.run([str(bin_dir / f"{peer}_driver"), str(plain), *flags],
                                 stdout=f, stderr=subprocess.DEVNULL, timeout=timeout)
    except subprocess.TimeoutExpired:
        return None, {"error": f"over {timeout:g} s"}
    wall = {"wall_s": round(time.perf_counter() - start, 2)}
    if run.returncode:
        return None, {**wall, "error": f"exit {run.returncode}"}
    subprocess.run([sys.executable, str(PEER_TUM), str(plain), str(out), str(tum)],
                   check=True, capture_output=True)
    return tum, wall


def one(peer: str, name: str, level: str, seed: int, bin_dir: Path, timeout: float) -> dict:
    """A Radish row: the peer's ATE against the corrected poses."""
    row = {"peer": peer, "log": name, "level": level, "seed": seed}
    with tempfile.TemporaryDirectory() as d:
        tum, got = run_peer(peer, prepared(name, level, seed), [], bin_dir, timeout, Path(d))
        row.update(got)
        if tum is not None:
            est = read_tum(tum)[:, 1:3]
            row["ate_m"] = round(ate(est, poses(radish_logs()[name])[:, :2]), 4)
    return row


def benchmark_row(peer: str, name: str, mode: str, bin_dir: Path, timeout: float) -> dict:
    """A benchmark log: the peer's relation error (``mode`` "local": Karto without its loop
    closing)."""
    path, rel, _laser = LOGS[name]
    row = {"peer": peer, "log": name, "mode": mode}
    flags = ["-loopClosing", "0"] if mode == "local" else []
    with tempfile.TemporaryDirectory() as d:
        tum, got = run_peer(peer, DATA / path, flags, bin_dir, timeout, Path(d))
        row.update(got)
        if tum is not None:
            score = json.loads(subprocess.run(
                [*DYNSLAM, "evaluate", str(tum), "--relations",
                 str(DATA / "relations" / f"{rel}.relations"), "--json"],
                check=True, capture_output=True, text=True).stdout)["relations"]
            row.update(trans_m=round(score["translational_m"]["mean"], 4),
                       rot_deg=round(score["rotational_deg"]["mean"], 3),
                       matched=score["matched"])
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--levels", default=",".join(LEVELS))
    ap.add_argument("--logs", default=",".join(radish_logs()))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--benchmark", help="benchmark logs (mit,intel,fr079): relations instead "
                    "of the Radish rows")
    ap.add_argument("--peers", default="karto,gmapping")
    ap.add_argument("--bin", type=Path, default=Path("/tmp/peers/bin"))
    ap.add_argument("--timeout", type=float, default=900.0)
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "peers.json")
    args = ap.parse_args()
    rows = []
    if args.benchmark:
        for name in args.benchmark.split(","):
            if LOGS[name][0].startswith("rosbag1/"):
                sys.exit(f"peers.py: {name} is a bag; the peers' drivers read Carmen logs")
            for peer in args.peers.split(","):
                for mode in MODES[peer]:
                    r = benchmark_row(peer, name, mode, args.bin, args.timeout)
                    rows.append(r)
                    figure = (f"{r['trans_m']} m {r['rot_deg']} deg" if "trans_m" in r
                              else r.get("error"))
                    print(f"{name:8} {peer:9} {mode:6} {figure!s:>22} {r.get('wall_s', '')}",
                          flush=True)
    else:
        for name in args.logs.split(","):
            for level in args.levels.split(","):
                for peer in args.peers.split(","):
                    r = one(peer, name, level, args.seed, args.bin, args.timeout)
                    rows.append(r)
                    print(f"{name:20} {level:9} {peer:9} "
                          f"{r.get('ate_m', r.get('error'))!s:>10} {r.get('wall_s', '')}",
                          flush=True)
    args.out.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
