"""Fuzzing the readers: whatever the bytes, a run ends in exit 0 (with counted skips) or in
exit 1 with one line — never a traceback, a crash signal or a hang. Property-based over the
text formats (hypothesis), seeded byte damage over the four containers. Settings sized for
CI; ``DYNSLAM_FUZZ_EXAMPLES=5000 pytest tests/test_fuzz.py`` runs a longer campaign."""

from __future__ import annotations

import os
import random
import shutil

import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dynslam_cli.cli import main

EXAMPLES = int(os.environ.get("DYNSLAM_FUZZ_EXAMPLES", "120"))
FUZZ = settings(max_examples=EXAMPLES, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow,
                                       HealthCheck.function_scoped_fixture])

NUMBERS = st.one_of(
    st.sampled_from(["0", "1", "-1", "2.0", "181", "nan", "inf", "-inf", "1e300", "-1e300",
                     "1e9", "0.0175", "3.14159", "180", "-1.5708", "8.0", "81.9", "1e-9"]),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-10**6, 10**6).map(str))
GARBAGE = st.text(alphabet=st.characters(codec="utf-8", exclude_categories=("Cs",)),
                  max_size=6)
TOKEN = st.one_of(NUMBERS, NUMBERS, NUMBERS, GARBAGE)
CARMEN_RECORDS = ["FLASER", "RLASER", "ROBOTLASER1", "RAWLASER1", "LASER3", "ODOM", "PARAM",
                  "TRUEPOS", "#"]
PLAYER_HEADS = ["laser 00 001 001", "laser 00 001 002", "laser 00 001 003", "laser 00 004 001",
                "position2d 00 001 001", "laser xx 001 001", "sync 00 001 001"]


def run(path, *extra: str):
    """dynslam process in this process; any exception but a clean exit fails the test."""
    r = CliRunner().invoke(main, ["process", str(path), "-o", str(path) + "_out", "--force",
                                  "-q", *extra], catch_exceptions=False)
    assert r.exit_code in (0, 1), r.stderr
    if r.exit_code == 1:
        assert r.stderr.startswith("dynslam: error: ") and r.stderr.count("\n") == 1, r.stderr
        assert r.stderr.isprintable() or r.stderr[:-1].isprintable(), r.stderr
    assert "Traceback" not in r.stderr
    return r


def carmen_line(record: str, tokens: list[str], stamp: int) -> str:
    return " ".join([record, *tokens, f"{stamp}.0", "h", f"{stamp}.0"])


@FUZZ
@given(st.lists(st.tuples(st.sampled_from(CARMEN_RECORDS), st.lists(TOKEN, max_size=200)),
                min_size=1, max_size=12), st.booleans())
def test_carmen_reader_never_crashes(tmp_path, lines, good_tail):
    text = "\n".join(carmen_line(r, t, i) for i, (r, t) in enumerate(lines, 1))
    if good_tail:  # a well-formed scan after the damage, so the run reaches the core
        text += "\nFLASER 5 1 1 1 1 1 0 0 0 0 0 0 99.0 h 99.0\nODOM 0 0 0 0 0 0 99.0 h 99.0"
    log = tmp_path / "fuzz.log"
    log.write_text(text + "\n", encoding="utf-8")
    run(log, "--format", "carmen")


@FUZZ
@given(st.sampled_from(["0.3.0", "0.2.0", "0.0.0", "9.9.9"]),
       st.lists(st.tuples(st.sampled_from(PLAYER_HEADS), st.lists(TOKEN, max_size=60)),
                min_size=1, max_size=10))
def test_player_reader_never_crashes(tmp_path, version, lines):
    text = f"## File version {version}\n" + "\n".join(
        f"{i}.0 host 6665 {head} {' '.join(t)}" for i, (head, t) in enumerate(lines, 1))
    log = tmp_path / "fuzz.log"
    log.write_text(text + "\n", encoding="utf-8")
    run(log, "--format", "player")


@FUZZ
@given(st.binary(max_size=4096))
def test_binary_garbage_is_refused_in_one_line(tmp_path, data):
    log = tmp_path / "garbage.log"
    log.write_bytes(data)
    run(log, "--format", "carmen")


@pytest.fixture(scope="module")
def containers(tmp_path_factory):
    """A short simulated run in each container: (name, the file to damage, what to run)."""
    root = tmp_path_factory.mktemp("bags")
    out = []
    for fmt in ("rosbag1", "rosbag2", "rosbag2-mcap", "mcap"):
        r = CliRunner().invoke(main, ["simulate", "crowd", "-o", str(root / fmt), "--duration",
                                      "3", "--format", fmt])
        assert r.exit_code == 0, r.output
        log = root / fmt / r.stdout.strip().split("/")[-1]
        data = log if log.is_file() else next(p for p in log.iterdir()
                                              if p.name != "metadata.yaml")
        out.append((fmt, data, log))
    return out


@pytest.mark.parametrize("seed", range(6))
def test_damaged_containers_end_cleanly(containers, tmp_path, seed):
    rng = random.Random(seed)
    for fmt, data, log in containers:
        folder = tmp_path / fmt
        shutil.copytree(log.parent, folder)
        target = folder / data.relative_to(log.parent)
        b = bytearray(target.read_bytes())
        if seed % 3 == 0:
            b = b[:rng.randrange(8, len(b))]  # cut off while written
        else:
            for _ in range(1 + seed):
                k = rng.randrange(len(b))
                b[k] ^= 1 << rng.randrange(8)
        target.write_bytes(bytes(b))
        run(folder / log.relative_to(log.parent))
