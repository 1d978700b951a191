from __future__ import annotations

import pytest

from dynslam_cli.config import load_config
from dynslam_cli.errors import ConfigError


def test_defaults_and_overrides(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text("[map]\nresolution_m = 0.1\n[laser]\nclear_cap_m = 4\n")
    c = load_config(p, {"map": {"p_hit": 0.7}})
    assert c.map.resolution_m == 0.1 and c.laser.clear_cap_m == 4.0 and c.map.p_hit == 0.7
    assert load_config().map.resolution_m == 0.05


@pytest.mark.parametrize(("text", "message"), [
    ("[map]\nresolutoin_m = 0.1\n", "unknown key"),
    ("[mapp]\nx = 1\n", "unknown key"),
    ("[map]\nresolution_m = 'fine'\n", "expected float"),
    ("[map]\nresolution_m = -1.0\n", "must be in \\[0.005, 10\\] m"),
    ("[map\n", "not valid TOML"),
    ("[map]\np_hit = 0.5000001\n", "map: the grids store log-odds as int16 steps"),
    ("[dynamic]\np_clamp_max = 0.999999999999999\n", "dynamic: .* the clamps within"),
    ("[match]\niterations = 30\n", "iterations is in \\[match.icp\\] now"),
    ("[laser]\nmount_y_m = -12.5\n", "laser.mount_y_m must be within 10 m of the robot"),
])
def test_bad_config_is_an_error(tmp_path, text, message):
    p = tmp_path / "c.toml"
    p.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_config(p)


def test_the_loop_closures_icp_is_tuned_apart_from_the_front_ends(tmp_path):
    """Tuning the front end's ICP leaves the loop closures' as it was, and the other way
    round (both once read ``[match]``'s)."""
    p = tmp_path / "c.toml"
    p.write_text("[match.icp]\niterations = 12\n[loop.icp]\nmax_correspondence_m = 1.0\n")
    c, default = load_config(p), load_config()
    assert c.match.icp.iterations == 12 and c.loop.icp.iterations == default.loop.icp.iterations
    assert c.loop.icp.max_correspondence_m == 1.0
    assert c.match.icp.max_correspondence_m == default.match.icp.max_correspondence_m


def test_dynslam_config_prints_a_config_file_that_loads_back(cli, tmp_path):
    import tomllib

    from dynslam_cli.config import Config, load_config

    r = cli("config")
    assert r.exit_code == 0
    text = r.stdout
    assert "# Cell edge length (metres).\nresolution_m = 0.05\n" in text
    assert "[ekf.noise]" in text and "# max_range_m =" in text  # unset: commented out
    assert tomllib.loads(text)["map"]["resolution_m"] == 0.05
    path = tmp_path / "all.toml"
    path.write_text(text)
    assert load_config(path) == Config()  # --config accepts what it prints
    tuned = tmp_path / "tuned.toml"
    tuned.write_text("[map]\nresolution_m = 0.1\n[ekf.noise]\nrange_m = 0.05\n")
    r = cli("config", "--config", tuned)
    path.write_text(r.stdout)
    assert load_config(path) == load_config(tuned)


def test_every_key_dynslam_config_prints_has_its_own_meaning(cli):
    """Each key (and table) comes under a comment of its own: about 20 keys came bare
    (max_landmarks, [ekf.noise] range_m, [loop] pending_closures, ...), or under their
    neighbour's comment (min_window_m under nothing, max_window_deg's '... at most this')."""
    import itertools
    import re

    key = re.compile(r"^(# )?(\w+) = ")
    lines = cli("config").stdout.splitlines()
    bare = [line for above, line in itertools.pairwise(lines)
            if (key.match(line) or line.startswith("[")) and
            (not above.startswith("#") or key.match(above))]
    assert bare == []
