"""Writers round-trip, and their files follow the outside conventions (map_server, TUM)."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image
from ruamel.yaml import YAML

from dynslam_cli.errors import InputError
from dynslam_cli.mapping.grid import OccupancyMap
from dynslam_cli.result import Landmark
from dynslam_formats.landmarks import HEADER, read_landmarks, write_landmarks
from dynslam_formats.mapfile import read_map, write_map
from dynslam_formats.tum import evo_ready, read_tum, write_tum


def nav2_load(yaml_path):
    """An OccupancyGrid's data (-1 unknown, 0-100) as nav2's map_io loadMapFromFile makes it:
    channels averaged (alpha too, inverted, in trinary mode), occ = 1 - shade, thresholds
    strict; scale mode calls a pixel unknown only when it is not opaque. Row 0 = lowest y."""
    meta = YAML(typ="safe").load(yaml_path.read_text())
    with Image.open(yaml_path.parent / meta["image"]) as im:
        rgba = np.asarray(im.convert("RGBA"), dtype=np.float64)
        matte = im.mode in ("LA", "RGBA", "PA")
    channels = [rgba[..., 0], rgba[..., 1], rgba[..., 2]]
    if meta["mode"] == "trinary" and matte:
        channels.append(rgba[..., 3])  # map_io's MaxRGB - alphaQuantum, i.e. the opacity
    shade = sum(channels) / len(channels) / 255.0
    occ = shade if meta["negate"] else 1.0 - shade
    free_t, occ_t = meta["free_thresh"], meta["occupied_thresh"]
    if meta["mode"] == "trinary":
        cells = np.where(occ_t < occ, 100, np.where(occ < free_t, 0, -1))
    else:
        scaled = np.rint((occ - free_t) / (occ_t - free_t) * 100.0)
        cells = np.where(occ_t < occ, 100, np.where(occ < free_t, 0, scaled))
        cells = np.where(rgba[..., 3] < 255, -1, cells)
    return cells.astype(np.int8)[::-1]


def test_maps_load_in_nav2_with_unknown_as_unknown(tmp_path):
    rng = np.random.default_rng(3)
    prob = rng.uniform(0.0, 1.0, (30, 40))
    prob[0, :3] = [0.0999, 0.1, 0.9001]  # right at the thresholds
    prob[0, 0] = 1.0  # lowest y, lowest x: must be the image's bottom-left pixel
    grid = OccupancyMap(prob=prob, resolution=0.1, origin_x=-2.0, origin_y=3.0)
    write_map(tmp_path, "static", grid, 0.1, 0.9, probabilities=True)
    expected = np.where(prob > 0.9, 100, np.where(prob < 0.1, 0, -1))
    assert (expected == -1).mean() > 0.7
    for name in ("static.yaml", "static_prob.yaml"):
        np.testing.assert_array_equal(nav2_load(tmp_path / name), expected, err_msg=name)

    meta = YAML(typ="safe").load((tmp_path / "static.yaml").read_text())
    assert meta == {"image": "static.pgm", "mode": "trinary", "resolution": 0.1,
                    "origin": [-2.0, 3.0, 0.0], "negate": 0, "occupied_thresh": 0.9,
                    "free_thresh": 0.1}
    raw = (tmp_path / "static.pgm").read_bytes()
    assert raw.startswith(b"P5")
    pixels = np.frombuffer(raw[-30 * 40:], np.uint8).reshape(30, 40)
    assert pixels[29, 0] == 0  # bottom-left pixel: occupied
    assert set(np.unique(pixels)) == {0, 205, 254}  # what map_saver writes


def test_probability_map_round_trip(tmp_path):
    prob = np.linspace(0.0, 1.0, 24).reshape(4, 6)
    grid = OccupancyMap(prob=prob, resolution=0.1, origin_x=-2.0, origin_y=3.0)
    write_map(tmp_path, "static", grid, 0.1, 0.9, probabilities=True)
    back = read_map(tmp_path / "static_prob.yaml")
    assert back.free_thresh == 0.1 and back.occupied_thresh == 0.9
    assert back.grid.origin_x == -2.0 and back.grid.resolution == 0.1
    np.testing.assert_allclose(back.grid.prob, prob, atol=1.5 / 255)
    trinary = read_map(tmp_path / "static.yaml").grid.prob  # the classes survive
    np.testing.assert_array_equal(trinary < 0.1, prob < 0.1)
    np.testing.assert_array_equal(trinary > 0.9, prob > 0.9)


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


def test_map_picture_is_cropped_upscaled_and_framed():
    from dynslam_formats.picture import (
        DYNAMIC_RGB,
        LANDMARK_RGB,
        MIN_PICTURE_PX,
        content_window,
        map_picture,
    )

    # A 4 m × 2 m room (0.05 m cells) inside a 40 m × 40 m grid cleared by far no-returns.
    prob = np.full((800, 800), 0.02)
    prob[400, 400:480] = prob[440, 400:480] = 1.0
    prob[400:441, 400] = prob[400:441, 480] = 1.0
    static = OccupancyMap(prob=prob, resolution=0.05, origin_x=-20.0, origin_y=-20.0)
    dynamic = OccupancyMap(prob=np.full_like(prob, 0.5), resolution=0.05, origin_x=-20.0,
                           origin_y=-20.0)
    traj = np.array([[0.0, 0.5, 0.5, 0.0], [1.0, 3.5, 1.5, 0.0]])
    c0, r0, c1, r1 = content_window(static, traj, [], 0.9)
    assert (c0, r0) == (380, 380) and (c1, r1) == (501, 461)  # the room and a metre around
    image, _ = map_picture(static, dynamic, traj, [Landmark(0, 0.0, 0.0, "convex", "static", 3)],
                        0.9)
    assert image.width >= MIN_PICTURE_PX * 0.9  # 121 cells at 6 px each, plus the frame
    colours = {c for _, c in image.getcolors(maxcolors=1 << 16)}
    assert DYNAMIC_RGB in colours and LANDMARK_RGB["dynamic"] in colours  # the legend


def _room_maps(rows: int = 60, cols: int = 80) -> tuple[OccupancyMap, OccupancyMap]:
    """A grid of ``rows`` × ``cols`` 0.05 m cells whose border is wall, free inside."""
    prob = np.full((rows, cols), 0.02)
    prob[[0, -1], :] = prob[:, [0, -1]] = 1.0
    return (OccupancyMap(prob, 0.05, 0.0, 0.0),
            OccupancyMap(np.full_like(prob, 0.5), 0.05, 0.0, 0.0))


def test_events_on_the_maps_edge_are_drawn_inside_the_picture_only():
    """Objects and a mover's path at the grid's edge and beyond it: the frame (ticks, scale
    bar, legend) is the same pixel for pixel as without them; inside, they are drawn."""
    from dynslam_cli.mapping.changes import ChangeEvent
    from dynslam_formats.picture import CHANGE_RGB, map_picture

    static, dynamic = _room_maps()
    traj = np.array([[0.0, 1.0, 1.0, 0.0], [1.0, 3.0, 2.0, 0.0]])
    events = [ChangeEvent(1, "appeared", 0.0, 1.0, 0.0, 0.0, 1.5, 9),
              ChangeEvent(22, "vacated", 0.0, 1.0, 3.95, 2.95, 2.0, 9),
              ChangeEvent(333, "moving", 0.0, 1.0, 2.0, 1.5, 0.1, 9,
                          path=((0.5, 1.5), (3.0, 1.5), (4.5, 3.5)))]
    plain, _ = map_picture(static, dynamic, traj, [], 0.9)
    drawn, _ = map_picture(static, dynamic, traj, [], 0.9, changes=events)
    assert plain.size == drawn.size
    a, b = np.asarray(plain).astype(int), np.asarray(drawn).astype(int)
    changed = np.argwhere(np.any(a != b, axis=2))
    assert len(changed) > 0
    # the frame's black outline: its top-left corner, and its bottom and right sides
    outline = np.argwhere(np.all(a == 0, axis=2))
    top, left = outline.min(axis=0)
    bottom = max(r for r, c in outline if c == left)
    right = max(c for r, c in outline if r == top)
    rows, cols = changed[:, 0], changed[:, 1]
    assert rows.min() > top and rows.max() < bottom and cols.min() > left and cols.max() < right
    colours = {tuple(c) for c in b[rows, cols]}
    assert all(tuple(CHANGE_RGB[e.kind]) in colours for e in events)


def test_a_busy_picture_draws_the_largest_events_and_says_how_many_more():
    """Two hundred events: the MAX_EVENTS_DRAWN largest are drawn, the frame says how many
    more changes.csv holds, and no two numbers overlap."""
    from PIL import ImageDraw

    from dynslam_cli.mapping.changes import ChangeEvent
    from dynslam_formats.picture import MAX_EVENTS_DRAWN, draw_changes, left_out_note

    rng = np.random.default_rng(5)
    events = [ChangeEvent(i + 1, "appeared", 0.0, 1.0, *rng.uniform(0, 4, 2),
                          float(rng.uniform(0.01, 1.0)), 9) for i in range(200)]
    image = Image.new("RGB", (400, 400), (255, 255, 255))
    draw = ImageDraw.Draw(image)
    boxes = []
    original = draw.text

    def text(xy, s, **kw):
        boxes.append(draw.textbbox(xy, s, font=kw["font"], anchor=kw["anchor"],
                                   stroke_width=kw["stroke_width"]))
        original(xy, s, **kw)

    draw.text = text
    left_out = draw_changes(draw, events, lambda x, y: (x * 100, 400 - y * 100), 100.0,
                            image.size)
    assert left_out == 200 - MAX_EVENTS_DRAWN
    assert "140 more in changes.csv" in left_out_note(200) and left_out_note(60) == ""
    assert 10 < len(boxes) <= MAX_EVENTS_DRAWN
    for i, a in enumerate(boxes):
        assert a[0] >= 0 and a[1] >= 0 and a[2] <= 400 and a[3] <= 400
        for b in boxes[:i]:
            assert not (a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3])


def test_snapshots_and_the_gif_carry_their_time_and_frame(tmp_path):
    """Snapshots are named by their seconds since the log began and framed like map.png."""
    from dynslam_cli.config import Config
    from dynslam_cli.result import SlamResult
    from dynslam_formats.picture import SnapshotWriter

    static, dynamic = _room_maps()
    writer = SnapshotWriter(tmp_path / "snapshots", 5.0, Config().map.occupied_threshold)

    class Running:
        def current(self) -> SlamResult:
            return SlamResult(static, dynamic, np.array([[100.0, 1.0, 1.0, 0.0]]))

    for stamp in (100.0, 103.0, 105.5, 111.0):
        writer.maybe_take(stamp, Running().current)
    writer.finish(SlamResult(static, dynamic, np.array([[112.25, 1.0, 1.0, 0.0]])))
    names = sorted(p.name for p in (tmp_path / "snapshots").iterdir())
    assert names == ["evolution.gif", "t000000.0s.png", "t000005.5s.png", "t000011.0s.png",
                     "t000012.2s.png"]
    with Image.open(tmp_path / "snapshots" / "t000005.5s.png") as im:
        assert im.width > 80 and im.height > 60 + 40  # the map, its ticks, bar and legend
    with Image.open(tmp_path / "snapshots" / "evolution.gif") as gif:
        assert gif.n_frames == 4 and gif.width > 80


@pytest.mark.parametrize("channels", [1, 2, 3])
def test_streamed_png_and_pgm_read_back_as_written(tmp_path, channels):
    from dynslam_formats.png import PgmWriter, PngWriter

    rng = np.random.default_rng(channels)
    shape = (301, 77) if channels == 1 else (301, 77, channels)
    pixels = rng.integers(0, 256, shape, dtype=np.uint8)
    pixels[100:200] = 7  # runs, as maps have
    with open(tmp_path / "a.png", "wb") as f:
        png = PngWriter(f, 77, 301, channels)
        for top in range(0, 301, 64):  # bands of rows, from the top
            png.add(pixels[top:top + 64])
        png.finish()
    with Image.open(tmp_path / "a.png") as im:
        im.load()
        assert im.mode == {1: "L", 2: "LA", 3: "RGB"}[channels]
        np.testing.assert_array_equal(np.asarray(im), pixels)
    if channels == 1:
        with open(tmp_path / "a.pgm", "wb") as f:
            pgm = PgmWriter(f, 77, 301)
            pgm.add(pixels[:150])
            pgm.add(pixels[150:])
        Image.fromarray(pixels, mode="L").save(tmp_path / "pil.pgm")
        assert (tmp_path / "a.pgm").read_bytes() == (tmp_path / "pil.pgm").read_bytes()


def test_a_very_large_map_picture_is_shrunk_keeping_walls():
    from dynslam_formats.picture import MAX_PICTURE_PX, map_picture

    prob = np.full((300, 9000), 0.02)  # a 450 m corridor of 0.05 m cells
    prob[[10, 290], :] = 1.0  # its walls, one cell thick
    static = OccupancyMap(prob, 0.05, 0.0, 0.0)
    dynamic = OccupancyMap(np.full_like(prob, 0.5), 0.05, 0.0, 0.0)
    traj = np.array([[0.0, 1.0, 7.5, 0.0], [1.0, 449.0, 7.5, 0.0]])
    image, pixels_per_cell = map_picture(static, dynamic, traj, [], 0.9)
    assert pixels_per_cell == 1 / 3 and image.width <= MAX_PICTURE_PX + 100
    grey = np.asarray(image.convert("L"))[10:110, 56:56 + 3000]  # the map inside the frame
    dark_rows = np.flatnonzero((grey == 0).mean(axis=1) > 0.9)
    assert list(dark_rows) == [3, 96]  # both one-cell walls survive the shrinking


def _evo_accepts(stamps: np.ndarray) -> bool:
    """evo's PoseTrajectory3D.check: stamps ascending, none repeated."""
    return bool(np.all(np.sort(stamps) == stamps) and np.unique(stamps).size == len(stamps))


def test_tum_stamps_are_ascending_and_unique_for_evo():
    """Logs with scans written late, repeated stamps or a stopped clock gave TUM files
    evo's --full_check refuses (issue 38, item 6)."""
    poses = np.arange(5.0)[:, None] * np.ones(3)
    fine = np.column_stack([[10.0, 10.1, 10.2, 10.3, 10.4], poses])
    assert np.array_equal(evo_ready(fine), fine)  # a good clock: unchanged, to the bit
    late = np.column_stack([[10.0, 10.2, 10.1, 10.3, 10.3], poses])
    out = evo_ready(late)
    assert _evo_accepts(out[:, 0])
    assert list(out[:, 1]) == [0, 2, 1, 3, 4]  # the late scan at its time
    assert out[4, 0] == pytest.approx(10.3 + 1e-6, abs=1e-9)  # a repeat moves up 1 µs
    stopped = np.column_stack([[-0.4, 4.3e9, 4.3e9, 4.3e9, 4.3e9], poses])
    out = evo_ready(stopped)
    assert list(out[:, 0]) == [0, 1, 2, 3, 4] and list(out[:, 1]) == [0, 1, 2, 3, 4]
    buf = io.StringIO()
    write_tum(buf, evo_ready(np.column_stack([np.zeros(5), poses])))
    assert [line.split()[0] for line in buf.getvalue().splitlines()] == [
        "0.000000", "1.000000", "2.000000", "3.000000", "4.000000"]


def test_the_legend_names_events_between_sessions_only_where_there_are_some():
    from dynslam_cli.mapping.changes import ChangeEvent
    from dynslam_formats.picture import legend

    gone = ChangeEvent(1, "removed_since_prior", 0.0, 1.0, 2.0, 2.0, 0.4, 9)
    moving = ChangeEvent(2, "moving", 0.0, 1.0, 2.0, 2.0, 0.1, 9)
    assert not any("removed_since_prior" in label for _, label in legend([moving]))
    assert any("removed_since_prior" in label for _, label in legend([moving, gone]))
