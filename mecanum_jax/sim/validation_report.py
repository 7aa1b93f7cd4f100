"""The physics validation's report: ``docs/physics_validation.md`` from the results of
:func:`mecanum_jax.sim.validation.run` (tracking, the X-square's spin, slip and odometry,
both fidelities side by side), and one fidelity's verdict in a line (:func:`summary`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import NotRequired, TypedDict

import numpy as np

TrackingRow = TypedDict(
    "TrackingRow",
    {
        "case": str,
        "command": list[float],
        "achieved": list[float],  # the mean true body twist over the last 0.5 s
        "linear_error": float,
        "angular_error": float,
        "pass": bool,
    },
)
"""One twist tracked from the analytic inverse model's wheel rates."""
SlipRow = TypedDict(
    "SlipRow",
    {
        "case": str,
        "group": str,
        "command": list[float],
        "mean_twist_first_0.5s": list[float],
        "final_pose": list[float],
        "odometry_error_m": float,
        "distance_m": float,
        "resets": int,
    },
)
"""One step command from rest: the acceleration phase's twist, the pose, the odometry."""


class Spin(TypedDict):
    """The X-square against the O-square under the O spin pattern, and its own inverse."""

    x_square_pattern_wz: float
    x_square_own_inverse_rates: list[float]
    x_square_own_inverse_wz: float
    o_square_pattern_wz: float


class FidelityResults(TypedDict):
    """One fidelity's results."""

    tracking: list[TrackingRow]
    slip: list[SlipRow]
    x_square: Spin
    unstable: int  # non-finite resets
    seconds: float  # wall time, with compilation


class Results(TypedDict):
    """What :func:`mecanum_jax.sim.validation.run` returns (and ``main`` adds to)."""

    robot: str
    quick: bool
    sim_overrides: NotRequired[dict[str, object]]  # the robots' [sim] fields overridden
    fast: NotRequired[FidelityResults]
    reference: NotRequired[FidelityResults]
    device: NotRequired[str]
    date: NotRequired[str]
    notes: NotRequired[str]


def fmt_vector(v: Sequence[float]) -> str:
    return "(" + ", ".join(f"{x:+.3f}" for x in v) + ")"


def summary(name: str, r: FidelityResults) -> str:
    """One fidelity's tracking verdict in a line."""
    rel = [
        np.linalg.norm(np.subtract(t["achieved"], t["command"])) / np.linalg.norm(t["command"])
        for t in r["tracking"]
    ]
    passed = sum(t["pass"] for t in r["tracking"])
    return (
        f"**{name}**: {passed}/{len(r['tracking'])} pass; relative twist error median "
        f"{100 * np.median(rel):.2f}%, max {100 * np.max(rel):.2f}%; non-finite resets: "
        f"{r['unstable']}; wall time {r['seconds']:.0f} s (with compilation)."
    )


def _flags(res: Results) -> str:
    """The command-line flags that reproduce ``res``."""
    flags = [" --quick"] if res["quick"] else []
    flags += [f" --{k} {v}" for k, v in res.get("sim_overrides", {}).items()]
    return "".join(flags)


def to_markdown(res: Results) -> str:
    """The validation results as docs/physics_validation.md."""
    fast, ref = res["fast"], res["reference"]
    lines = _tracking_md(res) + _x_square_md(fast, ref) + _slip_md(fast, ref)
    lines += ["", res.get("notes", ""), ""]
    return "\n".join(lines)


def _tracking_md(res: Results) -> list[str]:
    fast, ref = res["fast"], res["reference"]
    lines = [
        "# Physics validation: MJX model against the kinematics",
        "",
        f"Produced by `python -m mecanum_jax.sim.validation{_flags(res)}` "
        f"(robot `{res['robot']}`, {res['date']}, {res['device']}). Wheel rates come from the "
        "analytic inverse model; the achieved twist is the mean true body twist over the last "
        "0.5 s of 2 s, friction 1.0. Pass, fast fidelity: linear error ≤ max(2% |v|, 0.01 m/s) "
        "and angular error ≤ max(2% |ω|, 0.01 rad/s); reference fidelity: |error| ≤ 5% of "
        "|command| (norm of the twist).",
        "",
        "## Tracking",
        "",
        "| case | command (vx, vy, ωz) | fast: achieved | fast: lin / ang error | pass | reference: achieved | reference: lin / ang error | pass |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for a, b in zip(fast["tracking"], ref["tracking"], strict=True):
        lines.append(
            f"| {a['case']} | {fmt_vector(a['command'])} | {fmt_vector(a['achieved'])} | "
            f"{a['linear_error']:.4f} / {a['angular_error']:.4f} | {'✓' if a['pass'] else '✗'} | "
            f"{fmt_vector(b['achieved'])} | {b['linear_error']:.4f} / {b['angular_error']:.4f} | "
            f"{'✓' if b['pass'] else '✗'} |"
        )
    for name, r in (("fast", fast), ("reference", ref)):
        lines += ["", summary(name, r)]
    lines += [
        "",
        "The reference model's larger error comes from its discrete rollers: each is a chain "
        "of spheres sized to a barrel profile, so the wheel's envelope dips slightly between "
        "spheres and the contact jumps from roller to roller, and at speed the chassis "
        "vibrates on it. Straight capsule rollers (`sim.roller_spheres = 0`) made the rolling "
        "radius polygonal instead (their ends stand ≈3.4% of r beyond the radius for 10 "
        "rollers at 45°) and failed 2 of these 26 twists, up to 6.9% (docs/physics_model.md).",
        "",
    ]
    return lines


def _x_square_md(fast: FidelityResults, ref: FidelityResults) -> list[str]:
    lines = [
        "## X-square cannot spin in place",
        "",
        "| fidelity | O-square, rates (−10, −10, +10, +10) | X-square, same rates | X-square, its inverse of ω = 1 rad/s |",
        "|---|---|---|---|",
    ]
    for name, r in (("fast", fast), ("reference", ref)):
        s = r["x_square"]
        lines.append(
            f"| {name} | ωz = {s['o_square_pattern_wz']:+.3f} rad/s | ωz = {s['x_square_pattern_wz']:+.4f} rad/s | "
            f"rates {fmt_vector(s['x_square_own_inverse_rates'])}, ωz = {s['x_square_own_inverse_wz']:+.4f} rad/s |"
        )
    lines += [
        "",
        "Under the O spin pattern the X-square's wheels fight along its diagonals, whose "
        "floor rollers all point at the centre: no lever arm, ωz = 0 (seed 002). The "
        "reference model's rollers are mounted at `mjcf.mounted_roller_angle` (44.52° for 10 "
        "rollers), so that the floor roller's effective angle, which grows as the roller "
        "turns away from the bottom, averages the layout's 45°; mounted at 45° they act as "
        "45.48°, which gave the X-square a lever arm and ωz = −0.80 rad/s. What is left is of the order of 0.1 rad/s either "
        "way, the spin of a few hundredths of a degree of effective angle, while the chassis "
        "hops on its fighting wheels.",
    ]
    return lines


def _slip_md(fast: FidelityResults, ref: FidelityResults) -> list[str]:
    lines = [
        "",
        "## Slip where physics says, and odometry",
        "",
        "Step commands from rest. Mean twist over the first 0.5 s (the acceleration phase), final "
        "pose after 2 s, and the final position error of wheel odometry (encoders → "
        "`odometry.wheel_odometry` with the nominal geometry) against the true pose.",
        "",
        "| case | command | fast: mean twist 0–0.5 s | fast: final pose | fast: odometry error / distance | reference: mean twist 0–0.5 s | reference: final pose | reference: odometry error / distance |",
        "|---|---|---|---|---|---|---|---|",
    ]

    def pose(row: SlipRow) -> str:
        n = row.get("resets", 0)
        return fmt_vector(row["final_pose"]) + (f" **went unstable, reset {n}×**" if n else "")

    for a, b in zip(fast["slip"], ref["slip"], strict=True):
        lines.append(
            f"| {a['case']} | {fmt_vector(a['command'])} | {fmt_vector(a['mean_twist_first_0.5s'])} | {pose(a)} | "
            f"{a['odometry_error_m']:.3f} m / {a['distance_m']:.2f} m | {fmt_vector(b['mean_twist_first_0.5s'])} | "
            f"{pose(b)} | {b['odometry_error_m']:.3f} m / {b['distance_m']:.2f} m |"
        )
    return lines


__all__ = [
    "FidelityResults",
    "Results",
    "SlipRow",
    "Spin",
    "TrackingRow",
    "fmt_vector",
    "summary",
    "to_markdown",
]
