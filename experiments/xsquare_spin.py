"""Why the reference model's X-square spins under the O spin pattern (docs/physics_validation.md).

The kinematics say an X-square's floor rollers all point at the centre, so the O spin
pattern (−10, −10, +10, +10) rad/s makes its wheels fight along the diagonals with no
lever arm: ωz = 0. The reference (roller) model spun at −0.80 rad/s. Cause: a roller
turned by α about the axle has its axis tilted out of the floor plane, and it rolls freely
only across the floor projection of its axis, so its effective roller angle is
``tan γ(α) = tan γ₀ / cos α`` — 45.48° on average for 10 rollers mounted at γ₀ = 45°
(``mjcf.mounted_roller_angle``). With 45.48° the X-square's spin column is no longer zero:
the fighting wheels' friction gets a lever arm, in the sense the kinematics predict.

Checks, each one simulated rollout of the reference model in C MuJoCo (the same MJCF
that MJX runs; C is 10× faster on the CPU, and gives −0.90 rad/s at 2 s where MJX's
validation averaged −0.80 over 1.5–2 s):

1. the spin scales with the mean excess of 1/cos α, i.e. falls with the roller count
   (5, 10, 20 rollers mounted at 45°);
2. mounting the rollers at ``atan(tan 45° / mean sec α)`` (44.52° for 10: the model's
   default now) removes it;
3. the residual's sensitivity to the mounting angle (±0.06°);
4. the O-rectangle (the robot the policy is judged on) under the same test: its O spin
   pattern, its own null-space pattern (10·(1, −1, −1, 1): pure fight, kinematics say
   twist 0) and a 0.3 m/s lateral command, with both mountings.

Run: ``.venv/bin/python experiments/xsquare_spin.py`` (about 30 s on 2 CPU cores); figures
in docs/physics_model.md, raw output in docs/results/2026-11-25-xsquare-spin/.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
import warnings

import mujoco
import numpy as np

from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.kinematics.geometry import SingularLayoutWarning
from mecanum_jax.sim import mjcf
from mecanum_jax.sim.description import RobotDescription, builtin_description

SPIN = (-10.0, -10.0, 10.0, 10.0)
O_NULL = (10.0, -10.0, -10.0, 10.0)


def mean_sec(rollers: int) -> float:
    """Mean of 1/cos α over a floor roller's sweep |α| ≤ π/n."""
    a = math.pi / rollers
    return math.log(1.0 / math.cos(a) + math.tan(a)) / a


def robot(name: str, rollers: int, mounted_deg: float | None = None) -> RobotDescription:
    """``name`` with ``rollers`` rollers, mounted at ``mounted_deg`` (45: the model before
    the fix), or by default at the compensated angle of the description's 45°."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SingularLayoutWarning)
        desc = builtin_description(name)
    desc = dataclasses.replace(desc, sim=dataclasses.replace(desc.sim, rollers=rollers))
    if mounted_deg is not None:  # ask for the effective angle that this mounting produces
        tan = math.tan(math.radians(mounted_deg)) * mean_sec(rollers)
        desc = dataclasses.replace(
            desc,
            geometry=dataclasses.replace(
                desc.geometry, roller_angle_deg=math.degrees(math.atan(tan))
            ),
        )
    return desc


def simulate(desc: RobotDescription, rates: tuple[float, ...], seconds: float) -> np.ndarray:
    """Hold wheel-rate setpoints from rest (velocity servos, C MuJoCo): the body twist
    (vx, vy, ωz) at every physics step."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SingularLayoutWarning)
        m, idx = mjcf.build_model(desc, "reference", visual=False)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    f = idx.free_dof
    out = np.zeros((round(seconds / m.opt.timestep), 3))
    for k in range(len(out)):
        d.ctrl[idx.actuators] = rates
        mujoco.mj_step(m, d)
        v = d.xmat[idx.chassis_body].reshape(3, 3).T @ d.qvel[f : f + 3]
        out[k] = (v[0], v[1], d.qvel[f + 5])
    return out


def row(label: str, desc: RobotDescription, rates: tuple[float, ...], seconds: float) -> None:
    t0 = time.perf_counter()
    tw = simulate(desc, rates, seconds)
    steps_per_s = round(1.0 / desc.sim.reference_timestep)
    last = tw[-steps_per_s // 2 :].mean(axis=0)
    at = " ".join(f"{tw[round(t * steps_per_s) - 1, 2]:+.3f}" for t in (1.0, seconds))
    print(
        f"| {label} | ({last[0]:+.4f}, {last[1]:+.4f}, {last[2]:+.4f}) | {at} | "
        f"{time.perf_counter() - t0:.1f} s |",
        flush=True,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=2.0)
    args = parser.parse_args()
    s = args.seconds
    print("| rollers | mean 1/cos α | effective angle, mounted at 45° | compensated mounting |")
    print("|---|---|---|---|")
    for n in (5, 10, 20):
        comp = math.degrees(mjcf.mounted_roller_angle(math.radians(45.0), n))
        eff = math.degrees(math.atan(mean_sec(n)))
        print(f"| {n} | {mean_sec(n):.4f} | {eff:.2f}° | {comp:.2f}° |")
    xs = robot("x_square", 10).build_geometry(warn_singular=False)
    tilted = dataclasses.replace(xs, roller_angles=xs.roller_angles * (45.48 / 45.0))
    jac = np.asarray(kinematics.jacobian(tilted))
    print(
        f"\nX-square at 45.48°: spin column {[round(float(v), 4) for v in jac[:, 2]]} m "
        f"(at 45°: 0); least-squares twist of the O spin pattern: "
        f"{np.round(np.linalg.lstsq(jac, np.asarray(SPIN), rcond=None)[0], 1).tolist()}\n"
    )
    print(f"| case | twist, mean of the last 0.5 s of {s:g} s | ωz at 1 s, {s:g} s | wall |")
    print("|---|---|---|---|")
    for n in (5, 10, 20):
        row(f"X-square, O spin pattern, {n} rollers at 45°", robot("x_square", n, 45.0), SPIN, s)
    xsq = robot("x_square", 10)
    row("X-square, O spin pattern, 10 rollers, compensated", xsq, SPIN, s)
    row("X-square, reversed pattern, 10 rollers, compensated", xsq, tuple(-v for v in SPIN), s)
    for deg in (44.46, 44.58):  # how sensitive the residual is to the mounting
        row(f"X-square, O spin pattern, 10 rollers at {deg}°", robot("x_square", 10, deg), SPIN, s)
    o_geom = builtin_description("o_rectangle").build_geometry()
    lateral = tuple(float(v) for v in np.asarray(kinematics.inverse(o_geom, np.array([0, 0.3, 0]))))
    wz = float(np.asarray(kinematics.forward(o_geom, np.asarray(SPIN)))[2])
    for mounted, tag in ((45.0, "10 rollers at 45°"), (None, "compensated")):
        desc = robot("o_rectangle", 10, mounted)
        row(f"O-rectangle, O spin pattern (kinematics: ωz = {wz:+.3f}), {tag}", desc, SPIN, s)
        row(f"O-rectangle, null-space pattern (kinematics: 0), {tag}", desc, O_NULL, s)
        row(f"O-rectangle, lateral 0.3 m/s, {tag}", desc, lateral, s)


if __name__ == "__main__":
    main()
