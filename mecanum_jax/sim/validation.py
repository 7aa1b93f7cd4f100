"""Validate the physics against the kinematics; writes ``docs/physics_validation.md``.

Run: ``python -m mecanum_jax.sim.validation [--quick] [--out docs/physics_validation.md]``.
The report is written by :mod:`mecanum_jax.sim.validation_report`.

For both fidelities, on flat ground:

1. **Tracking**: seed 000's six motion modes and 20 random twists within the motor limits,
   commanded as wheel rates from the analytic inverse model at friction 1.0; the
   steady-state body twist (mean of the last 0.5 s of 2 s) against the command. Pass:
   linear error ≤ max(2% of |v|, 0.01 m/s) and angular error ≤ max(2% of |ω|, 0.01 rad/s)
   (the reference fidelity is held to 5%).
2. **X-square** cannot spin in place: the O-layout spin pattern and the X-square's own
   inverse of a spin, against an O-square given the same pattern.
3. **Slip** where physics says: friction 0.1 with an aggressive step command (the twist
   falls short while accelerating), and a payload far off centre with soft servos (the
   robot drifts off its line, seed 002 note 2).
4. **Odometry**: the wheel encoders through :func:`mecanum_jax.kinematics.odometry.wheel_odometry`
   against the true pose, with and without slip.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np

from mecanum_jax.config import ConfigError
from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.kinematics import odometry
from mecanum_jax.kinematics.geometry import SingularLayoutWarning
from mecanum_jax.kinematics.modes import SIX_MODES
from mecanum_jax.sim import physics
from mecanum_jax.sim.description import (
    IMPLS,
    SOLVERS,
    RobotDescription,
    builtin_description,
    check_physics,
)
from mecanum_jax.sim.mjcf import Fidelity
from mecanum_jax.sim.state import RobotParams, SimState, stack_params
from mecanum_jax.sim.validation_report import (
    Results,
    SlipRow,
    Spin,
    TrackingRow,
    fmt_vector,
    summary,
    to_markdown,
)
from mecanum_jax.tracing import prepare_tracing

if TYPE_CHECKING:
    import numpy.typing as npt

    from mecanum_jax.kinematics.geometry import WheelGeometry

RECORD_EVERY = 10  # physics steps between samples (50 Hz at 2 ms)
CHUNK = 16  # robots per vmapped rollout


@dataclasses.dataclass(frozen=True)
class Case:
    """One simulated run: wheel-rate setpoints held from rest, with parameter overrides."""

    name: str
    group: str
    rates: tuple[float, ...]
    twist: tuple[float, float, float] | None = None  # the command, when it is a twist
    params: tuple[tuple[str, npt.ArrayLike], ...] = ()


def simulate(
    robot: physics.Robot, cases: Sequence[Case], seconds: float, chunk: int = CHUNK
) -> dict[str, np.ndarray]:
    """Run all cases in one vmapped rollout; returns time series sampled every 10 steps."""
    steps = round(seconds / robot.dt)
    samples = steps // RECORD_EVERY
    params = stack_params([robot.nominal_params(**dict(c.params)) for c in cases])
    rates = jnp.asarray([c.rates for c in cases], jnp.float32)

    def one(cmd: jax.Array, p: RobotParams) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
        state = robot.reset(p)

        def body(s: SimState, _: None) -> tuple[SimState, tuple[jax.Array, ...]]:
            s = robot.step(s, cmd, p, substeps=RECORD_EVERY)
            sen = robot.sensors(s)
            return s, (sen.twist, sen.pose, sen.wheel_angle)

        s, (tw, pose, ang) = jax.lax.scan(body, state, None, length=samples)
        return tw, pose, ang, s.unstable

    # Chunks of CHUNK robots (the last one padded, so one compilation serves all): on the
    # CPU, jaxlib 0.10.2's batched LAPACK kernel (used by MJX's Newton solver) deadlocks in
    # its thread pool above a batch threshold (34 reference robots hung; docs/benchmarks.md).
    fn = jax.jit(jax.vmap(one))
    parts = []
    n = len(cases)
    for start in range(0, n, chunk):
        idx = np.minimum(np.arange(start, start + chunk), n - 1)
        sub = jax.tree_util.tree_map(lambda x, idx=idx: x[idx], (rates, params))
        parts.append([np.asarray(x)[: min(chunk, n - start)] for x in fn(*sub)])
    tw, pose, ang, unstable = (np.concatenate(xs) for xs in zip(*parts, strict=True))
    return {
        "twist": tw,
        "pose": pose,
        "wheel_angle": ang,
        "unstable": unstable,
        "dt": np.asarray(robot.dt * RECORD_EVERY),
    }


def _max_rate(desc: RobotDescription) -> float:
    return desc.motors.max_motor_rpm * 2 * math.pi / 60 / desc.motors.gear_ratio


def tracking_cases(desc: RobotDescription, n_random: int, seed: int = 0) -> list[Case]:
    geom = desc.build_geometry()
    cases = []
    for key, (label, unit, _) in SIX_MODES.items():
        scale = 1.0 if unit[2] != 0 else 0.3
        t = tuple(float(v) * scale for v in unit)
        cases.append(Case(f"{key[0]}) {label}", "mode", _rates(geom, t), t))  # type: ignore[arg-type]
    rng = np.random.default_rng(seed)
    limit = _max_rate(desc)
    for k in range(n_random):
        d = rng.normal(size=3) * np.array([1.0, 1.0, 3.0])
        d /= np.max(np.abs(np.asarray(kinematics.inverse(geom, d)))) / limit
        t = tuple(float(v) for v in d * rng.uniform(0.1, 0.5))
        cases.append(Case(f"random {k}", "random", _rates(geom, t), t))  # type: ignore[arg-type]
    return cases


def _rates(geom: WheelGeometry, twist: Sequence[float]) -> tuple[float, ...]:
    return tuple(
        float(v) for v in np.asarray(kinematics.inverse(geom, np.asarray(twist, np.float32)))
    )


def slip_cases(desc: RobotDescription) -> list[Case]:
    geom = desc.build_geometry()
    fwd, lat = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)
    cases = []
    for mu in (1.0, 0.1):
        for name, t in (("forward 1 m/s", fwd), ("lateral 1 m/s", lat)):
            cases.append(Case(f"{name}, μ = {mu}", "slip", _rates(geom, t), t, (("friction", mu),)))
    gentle = (0.4, 0.2, 0.5)
    cases.append(Case("gentle, ramped 1 m/s², μ = 1.0", "odometry", _rates(geom, gentle), gentle,
                      (("max_accel", 20.0),)))  # fmt: skip
    straight = (0.8, 0.0, 0.0)
    soft = (("kp", 0.3), ("friction", 0.5), ("payload_mass", 3.0))
    for label, com in (
        ("payload centred", (0.0, 0.0, 0.0)),
        ("payload off centre", (0.08, 0.1, 0.0)),
    ):
        cases.append(
            Case(
                f"{label}, 0.8 m/s",
                "com",
                _rates(geom, straight),
                straight,
                (*soft, ("payload_com", com)),
            )
        )
    return cases


def _tracking_error(
    achieved: np.ndarray, cmd: np.ndarray, fidelity: str
) -> tuple[float, float, bool]:
    """Fast: per part, ≤ max(2% of |v| or |ω|, 0.01); reference: ≤ 5% of the twist's norm."""
    lin = float(np.linalg.norm(achieved[:2] - cmd[:2]))
    ang = float(abs(achieved[2] - cmd[2]))
    v_cmd = float(np.linalg.norm(cmd[:2]))
    if fidelity == "fast":
        ok = lin <= max(0.02 * v_cmd, 0.01) and ang <= max(0.02 * abs(float(cmd[2])), 0.01)
    else:
        err = float(np.linalg.norm(achieved - cmd))
        ok = err <= max(0.05 * float(np.linalg.norm(cmd)), 0.01)
    return lin, ang, bool(ok)


def odometry_drift(robot: physics.Robot, out: dict[str, np.ndarray], i: int) -> tuple[float, float]:
    """Final position error (m) of wheel odometry against the truth, and the distance travelled."""
    angles = out["wheel_angle"][i]
    inc = np.diff(np.concatenate([np.zeros((1, angles.shape[1])), angles]), axis=0)
    est = np.asarray(odometry.wheel_odometry(robot.geometry, jnp.zeros(3), jnp.asarray(inc)))
    truth = out["pose"][i]
    dist = float(np.sum(np.linalg.norm(np.diff(truth[:, :2], axis=0), axis=-1)))
    return float(np.linalg.norm(est[-1, :2] - truth[-1, :2])), dist


def run(
    quick: bool = False,
    robot_name: str = "o_rectangle",
    fidelities: tuple[Fidelity, ...] = ("fast", "reference"),
    **sim: Any,  # fields of the [sim] table, each of its own type
) -> Results:
    """Run every validation case for ``fidelities``; returns the results as plain data.

    ``sim`` overrides fields of the robots' ``[sim]`` table (e.g. ``solver="cg"``) for
    comparing solver settings against the same cases.
    """
    desc = _with_sim(builtin_description(robot_name), sim)
    n_random = 4 if quick else 20
    results: Results = {"robot": robot_name, "quick": quick}
    track = tracking_cases(desc, n_random)
    slips = slip_cases(desc)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SingularLayoutWarning)
        xsq = _with_sim(builtin_description("x_square"), sim)
        osq = _with_sim(builtin_description("o_square"), sim)
    spin_pattern = (-10.0, -10.0, 10.0, 10.0)
    if sim:
        results["sim_overrides"] = sim
    for fidelity in fidelities:
        t0 = time.perf_counter()
        robot = physics.Robot(desc, fidelity, robots=CHUNK)
        out = simulate(robot, track + slips, seconds=2.0)
        n_avg = int(0.5 / out["dt"])
        rows: list[TrackingRow] = []
        for i, c in enumerate(track):
            achieved = out["twist"][i, -n_avg:].mean(axis=0)
            cmd = np.asarray(c.twist)
            lin, ang, ok = _tracking_error(achieved, cmd, fidelity)
            rows.append({"case": c.name, "command": cmd.tolist(), "achieved": achieved.tolist(),
                         "linear_error": lin, "angular_error": ang, "pass": ok})  # fmt: skip
        slip_rows: list[SlipRow] = []
        for j, c in enumerate(slips):
            i = len(track) + j
            early = out["twist"][i, : int(0.5 / out["dt"])].mean(axis=0)
            final_pose = out["pose"][i, -1]
            drift, dist = odometry_drift(robot, out, i)
            slip_rows.append({"case": c.name, "group": c.group, "command": list(c.twist or ()),
                              "mean_twist_first_0.5s": early.tolist(), "final_pose": final_pose.tolist(),
                              "odometry_error_m": drift, "distance_m": dist,
                              "resets": int(np.asarray(out["unstable"][i]).max())})  # fmt: skip
        # the X-square against the O-square, same spin pattern; and the X-square's own spin inverse
        xs = physics.Robot(xsq, fidelity, robots=CHUNK)
        os_ = physics.Robot(osq, fidelity, robots=CHUNK)
        own = _rates(xs.geometry, (0.0, 0.0, 1.0))
        x_out = simulate(xs, [Case("X-square, O spin pattern", "x", spin_pattern),
                              Case("X-square, its own inverse of ω = 1 rad/s", "x", own)], 2.0)  # fmt: skip
        o_out = simulate(os_, [Case("O-square, O spin pattern", "x", spin_pattern)], 2.0)
        spin: Spin = {
            "x_square_pattern_wz": float(x_out["twist"][0, -n_avg:, 2].mean()),
            "x_square_own_inverse_rates": list(own),
            "x_square_own_inverse_wz": float(x_out["twist"][1, -n_avg:, 2].mean()),
            "o_square_pattern_wz": float(o_out["twist"][0, -n_avg:, 2].mean()),
        }
        results[fidelity] = {"tracking": rows, "slip": slip_rows, "x_square": spin,
                             "unstable": int(out["unstable"].sum()), "seconds": time.perf_counter() - t0}  # fmt: skip
    return results


def _with_sim(desc: RobotDescription, sim: dict[str, Any]) -> RobotDescription:
    if not sim:
        return desc
    out = dataclasses.replace(desc, sim=dataclasses.replace(desc.sim, **sim))
    check_physics(out, "validation")
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="4 random twists instead of 20")
    parser.add_argument("--out", type=Path, default=Path("docs/physics_validation.md"))
    parser.add_argument(
        "--fidelities", nargs="+", choices=["fast", "reference"], default=["fast", "reference"]
    )
    parser.add_argument("--solver", choices=list(SOLVERS), help="override sim.solver")
    parser.add_argument("--iterations", type=int, help="override sim.iterations")
    parser.add_argument("--impl", choices=list(IMPLS), help="override sim.impl (MJX backend)")
    args = parser.parse_args(argv)
    prepare_tracing("highest")  # one number on every device (mecanum_jax.tracing)
    overrides = (("solver", args.solver), ("iterations", args.iterations), ("impl", args.impl))
    sim = {k: v for k, v in overrides if v is not None}
    try:
        res = run(quick=args.quick, fidelities=tuple(args.fidelities), **sim)
    except ConfigError as err:
        parser.error(str(err))
    dev = jax.devices()[0]
    res["device"] = f"{dev.platform}: {dev.device_kind}"
    res["date"] = time.strftime("%Y-%m-%d")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    both = "fast" in res and "reference" in res
    outputs = [(args.out.with_suffix(".json"), json.dumps(res, indent=1))]
    if both:  # the report compares the two; a partial run writes its JSON only
        outputs.append((args.out, to_markdown(res)))
    for path, text in outputs:
        tmp = path.with_suffix(path.suffix + ".tmp")
        tmp.write_text(text)
        tmp.replace(path)
    if both:
        print(to_markdown(res))
    else:
        for name in args.fidelities:
            r = res["fast"] if name == "fast" else res["reference"]
            print(summary(name, r))
            for row in r["slip"]:
                early, pose = row["mean_twist_first_0.5s"], row["final_pose"]
                print(
                    f"  {row['case']}: mean twist 0-0.5 s {fmt_vector(early)}, "
                    f"final pose {fmt_vector(pose)}, resets {row.get('resets', 0)}"
                )
        print(f"wrote {outputs[0][0]}")


if __name__ == "__main__":
    main()
