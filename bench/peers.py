"""The peers on bench/radish.py's rows: Karto and GMapping (built by ../shared/peers/build.sh)
run on the same Radish logs at the same odometry levels and seed, scored the same way (ATE
after SE(2) alignment, scan by scan), so a dynslam row is read beside them.

    python bench/peers.py [--levels perfect,moderate,harsh] [--logs intel,aces] [--seed 0]
                          [--peers karto,gmapping] [--bin /tmp/peers/bin] [--out FILE.json]

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

from dynslam_formats.tum import read_tum  # noqa: E402

PEER_TUM = ROOT.parent / "shared" / "peers" / "peer_tum.py"


def one(peer: str, name: str, level: str, seed: int, bin_dir: Path, timeout: float) -> dict:
    row = {"peer": peer, "log": name, "level": level, "seed": seed}
    log = prepared(name, level, seed)
    with tempfile.TemporaryDirectory() as d:
        plain = Path(d) / "log.txt"  # the drivers read a plain Carmen log
        if log.suffix == ".gz":
            with gzip.open(log, "rb") as src, open(plain, "wb") as dst:
                shutil.copyfileobj(src, dst)
        else:
            plain = log
        out, tum = Path(d) / "peer.out", Path(d) / "peer.tum"
        start = time.perf_counter()
        try:
            with open(out, "w") as f:
                run = subprocess.run([str(bin_dir / f"{peer}_driver"), str(plain)], stdout=f,
                                     stderr=subprocess.DEVNULL, timeout=timeout)
        except subprocess.TimeoutExpired:
            return {**row, "error": f"over {timeout:g} s"}
        row["wall_s"] = round(time.perf_counter() - start, 2)
        if run.returncode:
            return {**row, "error": f"exit {run.returncode}"}
        subprocess.run([sys.executable, str(PEER_TUM), str(plain), str(out), str(tum)],
                       check=True, capture_output=True)
        est = read_tum(tum)[:, 1:3]
    row["ate_m"] = round(ate(est, poses(radish_logs()[name])[:, :2]), 4)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--levels", default=",".join(LEVELS))
    ap.add_argument("--logs", default=",".join(radish_logs()))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--peers", default="karto,gmapping")
    ap.add_argument("--bin", type=Path, default=Path("/tmp/peers/bin"))
    ap.add_argument("--timeout", type=float, default=900.0)
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "peers.json")
    args = ap.parse_args()
    rows = []
    for name in args.logs.split(","):
        for level in args.levels.split(","):
            for peer in args.peers.split(","):
                r = one(peer, name, level, args.seed, args.bin, args.timeout)
                rows.append(r)
                print(f"{name:20} {level:9} {peer:9} "
                      f"{r.get('ate_m', r.get('error'))!s:>10} {r.get('wall_s', '')}", flush=True)
    args.out.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
