from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

ROOT = Path(__file__).resolve().parent.parent
DATASETS = ROOT.parent / "shared" / "datasets"
SAMPLES = ROOT / "samples"


@pytest.fixture
def datasets() -> Path:
    if not DATASETS.is_dir():
        pytest.skip("../shared/datasets is not here")
    return DATASETS


@pytest.fixture
def cli():
    """Run the dynslam CLI in-process; returns click's Result."""
    from dynslam_cli.cli import main

    runner = CliRunner()

    def invoke(*args: str, input: bytes | str | None = None):
        return runner.invoke(main, [str(a) for a in args], input=input, catch_exceptions=False)

    return invoke


def flaser(n: int = 5, r: float = 2.0, pose=(0.0, 0.0, 0.0), t: float = 1.0) -> str:
    ranges = " ".join(f"{r:.3f}" for _ in range(n))
    p = " ".join(f"{v:.6f}" for v in pose)
    return f"FLASER {n} {ranges} {p} {p} {t:.6f} host {t:.6f}\n"
