"""Robot description files: every shipped one loads; bad files are rejected clearly."""

import math
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from mecanum_jax import ConfigError, load_description
from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.sim.description import CONFIG_DIR, builtin_description

ROBOTS = sorted(p.stem for p in (CONFIG_DIR / "robots").glob("*.toml"))

GOOD = """
[robot]
name = "t"
[geometry]
layout = "O-rectangle"
wheel_radius = 0.05
half_wheelbase = 0.10
half_track = 0.125
[motors]
max_motor_rpm = 9000.0
gear_ratio = 19.0
"""


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "robot.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("name", ROBOTS)
def test_shipped_descriptions_load(name):
    desc = builtin_description(name)
    geom = desc.build_geometry(warn_singular=False)
    assert geom.n_wheels == len(desc.motor_signs(geom.names))
    rates = desc.max_wheel_rates(geom)
    assert bool(jnp.all(rates > 0))
    expected_rank = 2 if name == "x_square" else 3
    assert kinematics.jacobian_rank(geom) == expected_rank


def test_shipped_set_covers_every_layout():
    layouts = {builtin_description(n).geometry.layout for n in ROBOTS}
    assert layouts == {
        "O-square",
        "O-rectangle",
        "X-square",
        "X-rectangle",
        "centripetal",
        "custom",
    }


def test_description_matches_constructor(tmp_path):
    desc = load_description(write(tmp_path, GOOD))
    geom = desc.build_geometry()
    K = 0.10 + 0.125
    np.testing.assert_allclose(kinematics.jacobian(geom)[:, 2] * 0.05, [-K, -K, K, K], rtol=1e-6)
    assert desc.motor_signs(geom.names) == (1, 1, -1, -1)  # default: right side mirrored
    assert float(desc.max_wheel_rates(geom)[0]) == pytest.approx(9000 * 2 * math.pi / 60 / 19)


def test_custom_layout_wheel_by_wheel():
    desc = builtin_description("custom_six")
    geom = desc.build_geometry()
    assert geom.names[1] == "left_middle"
    assert float(geom.roller_angles[1]) == pytest.approx(math.radians(30))


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (
            lambda s: s.replace("half_track = 0.125", "half_trak = 0.125"),
            r"geometry\.half_trak = 0\.125: unknown key",
        ),
        (
            lambda s: s.replace("half_track = 0.125\n", ""),
            r"geometry\.half_track: missing required key",
        ),
        (lambda s: s.replace("[robot]\nname", "[robot]\nnmae"), r"robot\.nmae = 't': unknown key"),
        (
            lambda s: s.replace("max_motor_rpm = 9000.0\n", ""),
            r"motors\.max_motor_rpm: missing required key",
        ),
        (lambda s: s + "\n[extra]\nx = 1\n", r"extra = \{'x': 1\}: unknown key"),
        (
            lambda s: s.replace("wheel_radius = 0.05", "wheel_radius = -0.05"),
            r"radius = -0\.05: must be > 0",
        ),
        (
            lambda s: s.replace("wheel_radius = 0.05", 'wheel_radius = "big"'),
            r"geometry\.wheel_radius = 'big'",
        ),
        (
            lambda s: s.replace("wheel_radius = 0.05", "wheel_radius = nan"),
            r"geometry\.wheel_radius = nan",
        ),
        (
            lambda s: s.replace('"O-rectangle"', '"O-rect"'),
            r"geometry\.layout = 'O-rect': expected one of",
        ),
        (lambda s: s + "centre_distance = 0.2\n", r"motors\.centre_distance"),
        (
            lambda s: s.replace("half_track = 0.125", "half_track = 0.125\ncentre_distance = 0.2"),
            r"geometry\.centre_distance = 0\.2: not used by layout 'O-rectangle'",
        ),
        (lambda s: s + "signs = [1, 1, -1]\n", r"motors\.signs = \[1, 1, -1\]: expected 4 signs"),
        (lambda s: s + "signs = [1, 1, -1, 2]\n", r"motors\.signs\[3\] = 2: expected \+1 or -1"),
        (
            lambda s: s.replace("gear_ratio = 19.0", "gear_ratio = 0.0"),
            r"motors\.gear_ratio = 0\.0: must be > 0",
        ),
        (
            lambda s: s.replace("gear_ratio = 19.0", "gear_ratio = true"),
            r"motors\.gear_ratio = True: expected a number",
        ),
        (lambda s: s.replace("[motors]", "[motors"), r"invalid TOML"),
    ],
)
def test_bad_description_files(tmp_path, edit, match):
    with pytest.raises(ConfigError, match=match):
        load_description(write(tmp_path, edit(GOOD)))


def test_missing_file_and_unknown_builtin(tmp_path):
    with pytest.raises(ConfigError, match=r"no such file"):
        load_description(tmp_path / "nope.toml")
    with pytest.raises(ConfigError, match=r"robot = 'nope'.*known: \["):
        builtin_description("nope")


def test_custom_wheel_errors_name_the_wheel(tmp_path):
    src = (CONFIG_DIR / "robots" / "custom_six.toml").read_text()
    bad = src.replace("roller_angle_deg = 30.0", "roller_angle_deg = 90.0", 1)
    with pytest.raises(ConfigError, match=r"roller_angles\[1\] = .*'left_middle'"):
        load_description(write(tmp_path, bad))
    bad = src.replace('name = "left_middle"\n', "", 1)
    with pytest.raises(ConfigError, match=r"geometry\.wheels\[1\]\.name: missing required key"):
        load_description(write(tmp_path, bad))


def test_a_description_is_parsed_once_until_its_file_changes(tmp_path, monkeypatch):
    """The same file loads as the same (frozen) description without being parsed again;
    edited, it is parsed anew."""
    from mecanum_jax.sim import description

    parsed = []
    real = description.parse_description
    monkeypatch.setattr(
        description, "parse_description", lambda *a, **k: parsed.append(1) or real(*a, **k)
    )
    path = write(tmp_path, GOOD)
    first = load_description(path)
    assert load_description(str(path)) is first
    assert load_description(tmp_path / "." / "robot.toml") is first
    assert len(parsed) == 1
    with pytest.raises(AttributeError):
        first.motors.gear_ratio = 1.0  # type: ignore[misc]  # frozen: shared safely
    path.write_text(GOOD.replace("gear_ratio = 19.0", "gear_ratio = 20.0"))
    edited = load_description(path)
    assert len(parsed) == 2
    assert edited.motors.gear_ratio == 20.0
    assert load_description(path) is edited
