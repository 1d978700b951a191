"""Writers round-trip, and their files follow the outside conventions (map_server, TUM)."""

from __future__ import annotations

import io

import numpy as np
import pytest
from ruamel.yaml import YAML

from dynslam_cli.errors import InputError
from dynslam_cli.mapping.grid import OccupancyMap
from dynslam_cli.pipeline import Landmark
from formats.landmarks import HEADER, read_landmarks, write_landmarks
from formats.mapfile import read_map, write_map
from formats.tum import read_tum, write_tum


def test_map_round_trip_and_nav2_conventions(tmp_path):
    prob = np.full((4, 6), 0.5)
    prob[0, 0] = 1.0  # lowest y, lowest x: must be the image's bottom-left pixel
    prob[3, 5] = 0.0  # highest y, highest x: top-right
    grid = OccupancyMap(prob=prob, resolution=0.1, origin_x=-2.0, origin_y=3.0)
    write_map(tmp_path, "static", grid, 0.1, 0.9)

    meta = YAML(typ="safe").load((tmp_path / "static.yaml").read_text())
    assert meta == {"image": "static.pgm", "mode": "scale", "resolution": 0.1,
                    "origin": [-2.0, 3.0, 0.0], "negate": 0, "occupied_thresh": 0.9,
                    "free_thresh": 0.1}
    raw = (tmp_path / "static.pgm").read_bytes()
    assert raw.startswith(b"P5")
    pixels = np.frombuffer(raw[-24:], np.uint8).reshape(4, 6)
    assert pixels[3, 0] == 0  # bottom-left pixel: occupied, p = (255 - 0) / 255 = 1
    assert pixels[0, 5] == 255  # top-right: free
    assert pixels[1, 1] in (127, 128)

    back = read_map(tmp_path / "static.yaml")
    assert back.free_thresh == 0.1 and back.occupied_thresh == 0.9
    assert back.grid.origin_x == -2.0 and back.grid.resolution == 0.1
    np.testing.assert_allclose(back.grid.prob, prob, atol=0.5 / 255)


def test_tum_round_trip_and_layout():
    traj = np.array([[1.5, 1.0, -2.0, 0.3], [2.5, 1.1, -2.1, -3.0]])
    buf = io.StringIO()
    write_tum(buf, traj)
    lines = buf.getvalue().splitlines()
    assert all(len(line.split(" ")) == 8 and not line.endswith(" ") for line in lines)
    assert lines[0].startswith("1.500000 1.000000 -2.000000 0 0 0 ")


def test_tum_read_back(tmp_path):
    traj = np.array([[1.5, 1.0, -2.0, 0.3], [2.5, 1.1, -2.1, -3.0]])
    p = tmp_path / "t.tum"
    with open(p, "w") as f:
        write_tum(f, traj)
    np.testing.assert_allclose(read_tum(p), traj, atol=1e-6)


def test_tum_reader_is_strict(tmp_path):
    p = tmp_path / "bad.tum"
    p.write_text("# c\n1 2 3 0 0 0 0 1 \n")
    with pytest.raises(InputError, match="8 entries") as info:
        read_tum(p)
    assert info.value.line == 2


def test_landmarks_csv_round_trip():
    lms = [Landmark(0, 1.0, 2.0, "convex", "static", 5),
           Landmark(1, -1.5, 0.25, "concave", "dynamic", 1)]
    buf = io.StringIO()
    write_landmarks(buf, lms)
    assert buf.getvalue().splitlines()[0] == ",".join(HEADER)
    assert read_landmarks(io.StringIO(buf.getvalue())) == lms
