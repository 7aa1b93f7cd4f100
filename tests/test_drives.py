"""The other drives of seed 001 and the velocity-space comparison of seed 000 §4."""

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mecanum_jax.config import ConfigError
from mecanum_jax.evaluation import velocity_space
from mecanum_jax.kinematics import drive_description, drive_geometry, drives
from mecanum_jax.kinematics.model import icr as twist_icr

R, L, D = 0.05, 0.25, 0.20  # wheel radius, track, wheelbase (m)


def make(name, dtype=jnp.float32):
    return {
        "differential": lambda: drive_geometry.differential(R, L, dtype),
        "tricycle": lambda: drive_geometry.tricycle(R, D, math.radians(80), dtype),
        "synchronous": lambda: drive_geometry.synchronous(R, dtype),
        "ackermann": lambda: drive_geometry.ackermann(R, D, L, math.radians(35), dtype),
    }[name]()


def feasible_twists(name, n=64, seed=0):
    """Twists each drive can produce: no vy (or no ωz), curvature within steering."""
    rng = np.random.default_rng(seed)
    v = rng.uniform(-1.0, 1.0, n)
    if name == "synchronous":
        return np.stack([v, rng.uniform(-1, 1, n), np.zeros(n)], -1)
    kappa = rng.uniform(-1.5, 1.5, n)  # 1/m, within Ackermann's 35° (2.4 /m)
    w = v * kappa if name != "differential" else rng.uniform(-5, 5, n)
    return np.stack([v, np.zeros(n), w], -1)


# --- the formulas of seed 001, by hand --------------------------------------------------------


def test_differential_drive_formulas():
    g = make("differential")
    wl, wr = 8.0, 12.0
    VL, VR = R * wl, R * wr
    twist = np.asarray(drives.forward(g, [wl, wr]))
    # v = (V_R + V_L)/2, ω = (V_R − V_L)/L
    np.testing.assert_allclose(twist, [(VR + VL) / 2, 0.0, (VR - VL) / L], rtol=1e-6)
    # ICR: R = (L/2)(V_R + V_L)/(V_R − V_L), on the wheel axis (the body y axis)
    point = np.asarray(drives.icr(g, [wl, wr]).point)
    np.testing.assert_allclose(point, [0.0, (L / 2) * (VR + VL) / (VR - VL)], rtol=1e-5)
    # ω(R ± L/2) = V_R, V_L
    radius = point[1]
    np.testing.assert_allclose(twist[2] * (radius + L / 2), VR, rtol=1e-5)
    np.testing.assert_allclose(twist[2] * (radius - L / 2), VL, rtol=1e-5)


def test_tricycle_formulas():
    g = make("tricycle")
    alpha, ws = 0.4, 10.0
    vs = R * ws
    twist = np.asarray(drives.forward(g, [alpha, ws]))
    # v = v_s cos α, ω = (v_s/d) sin α
    np.testing.assert_allclose(twist, [vs * np.cos(alpha), 0, vs * np.sin(alpha) / D], rtol=1e-6)
    # the ICR lies on the rear-axle line at R = d tan(π/2 − α) from its midpoint
    point = np.asarray(drives.icr(g, [alpha, ws]).point)
    np.testing.assert_allclose(point, [0.0, D * np.tan(np.pi / 2 - alpha)], rtol=1e-5)
    # ω = ω_s r / sqrt(d² + R²): the same ω from the steered wheel's distance to the ICR
    np.testing.assert_allclose(twist[2], vs / np.hypot(D, point[1]), rtol=1e-5)
    # inverse: the (α, ω_s) for a (v, ω)
    np.testing.assert_allclose(drives.inverse(g, twist), [alpha, ws], rtol=1e-5)


def test_synchronous_drive_formulas():
    g = make("synchronous")
    phi, ww = 2.0, 6.0
    twist = np.asarray(drives.forward(g, [phi, ww]))
    # all wheels parallel: the chassis translates along φ at r·ω_w and does not rotate
    np.testing.assert_allclose(twist, [R * ww * np.cos(phi), R * ww * np.sin(phi), 0], atol=1e-7)
    icr = drives.icr(g, [phi, ww])
    assert bool(icr.translating)
    assert np.all(np.isnan(np.asarray(icr.point)))


def test_ackermann_condition_and_rear_wheels():
    g = make("ackermann")
    v, radius = 0.8, 1.0  # a left turn about (0, 1 m)
    left, right, rl, rr = np.asarray(drives.inverse(g, [v, 0.0, v / radius]))
    # each front wheel rolls perpendicular to its line to the ICR: tan δ = l / (R ∓ d/2)
    np.testing.assert_allclose(np.tan(left), D / (radius - L / 2), rtol=1e-5)
    np.testing.assert_allclose(np.tan(right), D / (radius + L / 2), rtol=1e-5)
    # the Ackermann condition with physics' sign: the inner wheel turns more, so
    # cot δ_outer − cot δ_inner = d / l (seed 001 prints cot θ_i − cot θ_o = d/l)
    assert left > right > 0
    np.testing.assert_allclose(1 / np.tan(right) - 1 / np.tan(left), L / D, rtol=1e-5)
    assert not np.isclose(1 / np.tan(left) - 1 / np.tan(right), L / D)
    # rear wheels: an open differential, v ∓ ω d/2
    w = v / radius
    np.testing.assert_allclose([rl, rr], [(v - w * L / 2) / R, (v + w * L / 2) / R], rtol=1e-5)


# --- round trips, ICR special cases ------------------------------------------------------------


@pytest.mark.parametrize("name", drive_geometry.DRIVES)
def test_forward_inverts_inverse_for_feasible_twists(name, x64):
    g = make(name, jnp.float64)
    t = feasible_twists(name)
    np.testing.assert_allclose(drives.forward(g, drives.inverse(g, t)), t, atol=1e-12)
    assert bool(np.all(drives.reachable(g, t)))
    np.testing.assert_allclose(drives.residual(g, t), 0.0, atol=1e-12)


@pytest.mark.parametrize("name", ["differential", "tricycle", "ackermann"])
def test_icr_special_cases(name):
    g = make(name)
    straight = drives.inverse(g, [0.5, 0.0, 0.0])
    icr = drives.icr(g, straight)
    assert bool(icr.translating)  # R = ∞
    if name == "differential":
        spin = drives.icr(g, [-5.0, 5.0])  # V_R = −V_L: R = 0
        np.testing.assert_allclose(spin.point, [0.0, 0.0], atol=1e-7)
    if name == "tricycle":
        full = drive_geometry.tricycle(R, D, math.pi / 2)
        for sign in (1.0, -1.0):  # α = ±90°: a spin about the rear-axle midpoint
            twist = np.asarray(drives.forward(full, [sign * math.pi / 2, 10.0]))
            np.testing.assert_allclose(twist, [0.0, 0.0, sign * R * 10.0 / D], atol=1e-6)
            point = drives.icr(full, [sign * math.pi / 2, 10.0]).point
            np.testing.assert_allclose(point, 0.0, atol=1e-7)
            back = drives.inverse(full, twist)
            np.testing.assert_allclose(back, [sign * math.pi / 2, 10.0], rtol=1e-5)


def test_icr_of_drives_agrees_with_the_twist_icr():
    g = make("differential")
    a = np.array([[3.0, 7.0], [7.0, 3.0], [-2.0, 4.0]])
    np.testing.assert_allclose(
        drives.icr(g, a).point, twist_icr(drives.forward(g, a)).point, rtol=1e-6
    )


def test_odometry_integrates_a_circle_exactly(x64):
    g = make("differential", jnp.float64)
    a = jnp.broadcast_to(drives.inverse(g, [0.5, 0.0, 0.5]), (100, 2))  # R = 1 m
    poses = drives.wheel_odometry(g, jnp.zeros(3), a, dt=2 * math.pi / 0.5 / 100)
    np.testing.assert_allclose(poses[-1], [0.0, 0.0, 2 * math.pi], atol=1e-9)
    np.testing.assert_allclose(poses[49, :2], [0.0, 2.0], atol=1e-9)  # half way: (0, 2R)


# --- limits -----------------------------------------------------------------------------------


def test_limits_and_desaturation():
    g = make("differential")
    top = 50.0  # rad/s
    t = np.array([[R * top, 0.0, 0.0], [2 * R * top, 0.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(drives.saturation(g, t, top), [1.0, 2.0, L / 2 / R / top])
    assert list(np.asarray(drives.is_feasible(g, t, top))) == [True, False, True]
    scaled, scale = drives.desaturate(g, t, top)
    np.testing.assert_allclose(scale, [1.0, 0.5, 1.0])
    np.testing.assert_allclose(scaled[1], [R * top, 0, 0], rtol=1e-6)
    # sideways: not producible at all, flagged and dropped only on request
    assert not bool(drives.is_feasible(g, [0.0, 0.3, 0.0], top))
    np.testing.assert_allclose(drives.residual(g, [0.2, 0.3, 0.0]), [0, 0.3, 0], atol=1e-7)
    np.testing.assert_allclose(drives.max_speed(g, [[1, 0, 0], [0, 1, 0]], top), [R * top, 0])
    # Ackermann: a spin in place is beyond any steering limit < 90°
    assert not bool(drives.reachable(make("ackermann"), [0.0, 0.0, 1.0]))


# --- bad input --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: drive_geometry.differential(R, -0.3), r"track = -0\.3: must be > 0 m"),
        (lambda: drive_geometry.tricycle(0.0, D), r"wheel_radius = 0: must be > 0 m"),
        (lambda: drive_geometry.ackermann(R, D, L, math.radians(90)), r"max_steer = 1\.570796 rad"),
        (
            lambda: drives.inverse(make("differential"), [[0.1, 0, 0], [0.3, 0.2, 0.1]]),
            r"twist\[1\] = \(0\.3, 0\.2, 0\.1\): a differential drive cannot move sideways",
        ),
        (
            lambda: drives.inverse(make("synchronous"), [0.3, 0.0, 0.5]),
            r"chassis does not rotate \(wz must be 0",
        ),
        (
            lambda: drives.inverse(make("ackermann"), [0.2, 0.0, -0.5]),
            r"twist = \(0\.2, 0, -0\.5\): needs more steering than max_steer = 35°",
        ),
        (
            lambda: drives.forward(make("tricycle"), [1.5, 3.0]),
            r"actuators\[\.\.\., 0\] \(steer\) = 1\.5 rad \(85\.94367°\): beyond max_steer = 80°",
        ),
        (lambda: drives.forward(make("differential"), [1.0, 2.0, 3.0]), r"last axis must have"),
        (lambda: drives.saturation(make("differential"), [1, 0, 0], -1.0), r"max_rate = -1"),
    ],
)
def test_bad_input_names_field_and_value(call, message):
    with pytest.raises(
        drive_geometry.DriveError if "last axis" not in message else ValueError
    ) as err:
        call()
    assert err.match(message)


def test_descriptions_load_and_bad_ones_name_the_field(tmp_path):
    for name in drive_geometry.DRIVES:
        desc = drive_description.load_drive(name)
        assert desc.robot.drive == name
        assert desc.build().name == name
    bad = tmp_path / "bad.toml"
    bad.write_text(
        '[robot]\nname = "x"\ndrive = "tricycle"\n[geometry]\nwheel_radius = 0.05\n'
        "[motors]\nmax_motor_rpm = 100.0\n"
    )
    with pytest.raises(drive_geometry.DriveError, match=r"geometry\.wheelbase: missing"):
        drive_description.load_drive(str(bad))
    bad.write_text(bad.read_text().replace("0.05\n", "0.05\nwheelbase = 0.2\ntrack = 0.3\n"))
    with pytest.raises(
        drive_geometry.DriveError, match=r"geometry\.track = 0\.3: a tricycle drive"
    ):
        drive_description.load_drive(str(bad))
    with pytest.raises(ConfigError, match=r"robot = 'hovercraft': no such built-in drive"):
        drive_description.load_drive("hovercraft")
    # the steering limit is named in the unit it was given, and 0 is not "the default"
    steer = '[robot]\nname = "x"\ndrive = "ackermann"\n[geometry]\nwheel_radius = 0.05\n'
    for value in ("0.0", "90.0", "-10.0"):
        bad.write_text(
            steer + f"wheelbase = 0.2\ntrack = 0.3\nmax_steer_deg = {value}\n"
            "[motors]\nmax_motor_rpm = 100.0\n"
        )
        with pytest.raises(
            drive_geometry.DriveError, match=rf"geometry\.max_steer_deg = {value}: "
        ):
            drive_description.load_drive(str(bad))


# --- batching, jit, vmap, grad ----------------------------------------------------------------


@pytest.mark.parametrize("name", drive_geometry.DRIVES)
def test_batched_and_jitted_match_eager(name):
    g = make(name)
    t = feasible_twists(name, 12).reshape(3, 4, 3).astype(np.float32)
    eager = drives.inverse(g, t)
    jitted = jax.jit(lambda g, t: drives.inverse(g, t, strict=False))(g, t)
    np.testing.assert_allclose(jitted, eager, rtol=1e-6, atol=1e-6)
    one = np.stack([drives.inverse(g, x) for x in t.reshape(-1, 3)]).reshape(eager.shape)
    np.testing.assert_allclose(eager, one, rtol=1e-6, atol=1e-6)
    fw = jax.jit(drives.forward)(g, eager)
    np.testing.assert_allclose(fw, t, atol=2e-5)


def test_vmap_over_geometries_and_grad_through_forward():
    radii = jnp.array([0.04, 0.05, 0.06])
    geoms = jax.vmap(lambda r: drive_geometry.Differential(r, jnp.asarray(L)))(radii)
    twists = jax.vmap(drives.forward, in_axes=(0, None))(geoms, jnp.array([10.0, 10.0]))
    np.testing.assert_allclose(twists[:, 0], radii * 10.0, rtol=1e-6)

    def speed(r):
        return drives.forward(
            drive_geometry.Ackermann(r, jnp.asarray(D), jnp.asarray(L), 0.6),
            jnp.array([0.1, 0.09, 10.0, 12.0]),
        )[0]

    np.testing.assert_allclose(jax.grad(speed)(jnp.asarray(R)), 11.0, rtol=1e-6)  # v = r·mean


# --- seed 000 §4: the velocity spaces ---------------------------------------------------------


@pytest.mark.full  # float64 hulls of every drive: eight seconds on 2 cores
def test_velocity_spaces_are_polytopes_not_boxes(x64):
    """Seed 000 §4.1 calls the differential drive's (v, ω) set a rectangle and the mecanum
    platform's (vx, vy, ω) set a cuboid. With per-wheel rate limits they are a rhombus and
    an octahedron: a sixth of the box the seed draws."""
    spaces, top = velocity_space.compare()
    by = {s.drive: s for s in spaces}
    a = R * top  # the rim speed limit, m/s
    diff = by["differential"]
    np.testing.assert_allclose(diff.area_v_wz, 4 * a**2 / L, rtol=1e-4)  # rhombus
    box = (2 * diff.max_vx) * (2 * diff.max_wz)
    np.testing.assert_allclose(diff.area_v_wz / box, 0.5, rtol=1e-4)
    mec = by["mecanum"]
    k = 0.10 + 0.125  # o_rectangle: rx + ry
    np.testing.assert_allclose(mec.volume, 4 / 3 * a**3 / k, rtol=1e-6)  # |vx|+|vy|+k|ω| <= a
    np.testing.assert_allclose(
        mec.volume / (8 * mec.max_vx * mec.max_vy * mec.max_wz), 1 / 6, rtol=1e-6
    )
    np.testing.assert_allclose(by["synchronous"].area_vx_vy, math.pi * a**2, rtol=1e-4)
    assert diff.area_vx_vy == 0
    assert by["synchronous"].area_v_wz == 0
    # seed 000 §4.2: mecanum wheels' forces partly cancel; ordinary wheels' do not
    np.testing.assert_allclose(mec.force_efficiency_forward, 1 / math.sqrt(2), rtol=1e-6)
    assert diff.force_efficiency_forward == pytest.approx(1.0)
    assert diff.force_efficiency_sideways == 0.0
    assert by["synchronous"].force_efficiency_sideways == pytest.approx(1.0)


@pytest.mark.full
def test_comparison_command_writes_table_json_and_plot(tmp_path, capsys, monkeypatch):
    from mecanum_jax import bench

    monkeypatch.setenv("COLUMNS", "200")
    bench.main(["drives", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    for name in ("o_rectangle", *drive_geometry.DRIVES):
        assert name in out
    data = json.loads((tmp_path / "velocity_spaces.json").read_text())
    assert [s["drive"] for s in data["spaces"]] == ["mecanum", *drive_geometry.DRIVES]
    png = (tmp_path / "velocity_spaces.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(png) > 20_000
