"""Does the fast model's spurious roller inertia cause its centre-of-mass drift?

The fast model's hub turns with the carrier about the roller axis, so its "roller" carries
the hub's inertia (docs/physics_model.md). This probe builds a variant without it: the
hub's mass moved onto the chassis, the hub nearly massless (1 g), and its spin inertia
kept as axle armature (``motors.rotor_inertia`` reflected through the gear). Both run the
validation's slip cases (fast fidelity, 2 s) and print the mean twist over the first
0.5 s, the final pose and the robots reset as unstable.

    .venv/bin/python experiments/com_drift_probe.py
"""

import dataclasses

import numpy as np

from mecanum_jax.sim import physics, validation
from mecanum_jax.sim.description import builtin_description


def main() -> None:
    base = builtin_description("o_rectangle")
    m, r = base.body.wheel_mass, float(np.max(np.asarray(base.build_geometry().radii)))
    spin = 0.5 * m * r * r
    light = dataclasses.replace(
        base,
        body=dataclasses.replace(base.body, wheel_mass=1e-3, mass=base.body.mass + 4 * m),
        motors=dataclasses.replace(base.motors, rotor_inertia=spin / base.motors.gear_ratio**2),
    )
    cases = validation.slip_cases(base)
    for label, desc in (("default", base), ("light hub + armature", light)):
        robot = physics.Robot(desc, "fast")
        out = validation.simulate(robot, cases, seconds=2.0, chunk=len(cases))
        n = int(0.5 / out["dt"])
        for i, c in enumerate(cases):
            resets = int(np.asarray(out["unstable"][i]).max())
            print(
                f"{label:20s} {c.name:30s} mean twist 0-0.5 s "
                f"{np.round(out['twist'][i, :n].mean(0), 3)}, final pose "
                f"{np.round(out['pose'][i, -1], 3)}, unstable {resets}",
                flush=True,
            )


if __name__ == "__main__":
    main()
