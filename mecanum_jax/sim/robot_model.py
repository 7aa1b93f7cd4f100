"""The compiled robot and its per-robot parameters: the MJCF built at one fidelity, put into
MJX, and each robot's :class:`~mecanum_jax.sim.state.RobotParams` written into its copy
of the ``mjx.Model`` (:meth:`RobotModel.model_for`, traceable, so domain randomisation
needs no rebuild). :class:`mecanum_jax.sim.physics.Robot` steps it.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

# isort: split
import mecanum_jax._quiet_mjx  # noqa: F401  (first: keeps MJX's Warp probe quiet)

# isort: split
import jax
import jax.numpy as jnp
from mujoco import mjx

from mecanum_jax.kinematics.geometry import WheelGeometry
from mecanum_jax.sim import mjcf
from mecanum_jax.sim.description import RobotDescription, require_impl
from mecanum_jax.sim.servo import CHORD_WARP_RANGE, ServoModel, axle_inverse_inertia
from mecanum_jax.sim.state import RobotParams, nominal_params
from mecanum_jax.sim.warp_cache import leave_the_persistent_cache
from mecanum_jax.sim.warp_streams import pin_external_streams

if TYPE_CHECKING:
    import numpy.typing as npt


class RobotModel:
    """A robot compiled at one fidelity: the host model, its MJX model, and its index, and
    each robot's parameters written into a copy of the MJX model."""

    def __init__(
        self,
        desc: RobotDescription,
        fidelity: mjcf.Fidelity = "fast",
        servo: ServoModel = "chord",
        strip_visual: bool = True,
        robots: int = 1,
    ):
        """``strip_visual``: simulate a copy of the model without its draw-only geoms
        (:func:`mjcf.build_model`, same dynamics, fewer poses per step); ``mj_model``
        keeps them for rendering.

        ``robots``: with ``desc.sim.impl == "warp"``, the most robots one batched call
        simulates (all vmapped axes together): MuJoCo Warp's contact buffer is one for the
        whole batch, sized :data:`WARP_CONTACTS` per wheel and robot. The ``jax``
        implementation ignores it."""
        if servo not in ("chord", "mjx"):
            raise ValueError(f"servo = {servo!r}: must be 'chord' or 'mjx'")
        if not isinstance(robots, int) or robots < 1:
            raise ValueError(f"robots = {robots!r}: must be an integer >= 1")
        self.desc = desc
        self.fidelity = fidelity
        self.servo = servo
        self.impl = desc.sim.impl
        require_impl(self.impl)
        if self.impl == "warp":
            leave_the_persistent_cache()
            pin_external_streams()  # Warp's "unknown stream" (warp_streams.py)
        self._chord_on_warp = servo == "chord" and self.impl == "warp"
        self.robots = robots
        self.mj_model, self.index = mjcf.build_model(desc, fidelity)
        self.sim_model = self.mj_model
        if strip_visual:  # geom indices change: the index must be the simulated model's
            self.sim_model, self.index = mjcf.build_model(desc, fidelity, visual=False)
        # MJX's default device is jax.devices()[0], which another process of a
        # jax.distributed run cannot address; this process's first device always works
        self.mjx_model = mjx.put_model(
            self.sim_model, device=jax.local_devices()[0], impl=self.impl
        )
        if self.impl == "warp":
            self.mjx_model = _quiet_solver_limits(self.mjx_model)
        self.geometry: WheelGeometry = desc.build_geometry(warn_singular=False)
        self.n_wheels = self.geometry.n_wheels
        self.dt = float(self.mj_model.opt.timestep)
        per_robot = WARP_CONTACTS[fidelity] * self.n_wheels
        self.naconmax = per_robot * robots  # warp: contacts of the whole batch
        self.njmax = 4 * per_robot  # warp, per robot: a pyramidal condim-3 contact has 4 rows
        idx = self.index
        self._axle_qpos = jnp.asarray(idx.axle_qpos)
        self._axle_dof = jnp.asarray(idx.axle_dof)
        self._carrier_qpos = jnp.asarray(idx.carrier_qpos)
        self._acts = jnp.asarray(idx.actuators)
        self._wheel_geoms = jnp.asarray(idx.wheel_geoms)
        m = self.sim_model
        self._base_mass = float(m.body_mass[idx.chassis_body])
        self._base_ipos = jnp.asarray(m.body_ipos[idx.chassis_body])
        self._base_inertia = jnp.asarray(m.body_inertia[idx.chassis_body])
        self._geom_size = jnp.asarray(m.geom_size)
        self._geom_pos = jnp.asarray(m.geom_pos)
        self._roller_bodies = jnp.asarray(idx.roller_bodies)
        self._body_pos = jnp.asarray(m.body_pos)
        self._qpos0 = jnp.asarray(m.qpos0)
        self._axle_inv_inertia = jnp.asarray(axle_inverse_inertia(m, idx.axle_dof), jnp.float32)

    # --- parameters -------------------------------------------------------------------

    def nominal_params(self, **overrides: npt.ArrayLike) -> RobotParams:
        """The description's nominal parameters, with any field overridden (scalars broadcast)."""
        return nominal_params(self.desc, self.n_wheels, **overrides)

    def model_for(self, params: RobotParams) -> mjx.Model:
        """This robot's MJX model with ``params`` written in (traceable; batched under vmap)."""
        m = self.mjx_model
        idx = self.index
        friction = m.geom_friction.at[self._wheel_geoms, 0].set(
            jnp.broadcast_to(params.friction[:, None], self._wheel_geoms.shape)
        )
        # payload: a point mass at payload_com, combined with the chassis about the new CoM
        mb, mp = self._base_mass, params.payload_mass
        total = mb + mp
        com = (mb * self._base_ipos + mp * params.payload_com) / total
        db, dp = self._base_ipos - com, params.payload_com - com

        def point(mass: jax.Array | float, d: jax.Array) -> jax.Array:
            return mass * jnp.array(
                [d[1] ** 2 + d[2] ** 2, d[0] ** 2 + d[2] ** 2, d[0] ** 2 + d[1] ** 2]
            )

        inertia = self._base_inertia + point(mb, db) + point(mp, dp)
        c = idx.chassis_body
        gain = m.actuator_gainprm.at[self._acts, 0].set(params.kp)
        bias = m.actuator_biasprm.at[self._acts, 2].set(-params.kp)
        # MuJoCo Warp drops a clamped actuator's damping from the implicit step, but the
        # chord servo's own slope already keeps every force within the limit, so under
        # warp its clamp sits beyond reach: the slope stays implicit, as under MJX's JAX
        limit = params.torque_limit * (CHORD_WARP_RANGE if self._chord_on_warp else 1.0)
        frange = m.actuator_forcerange.at[self._acts].set(jnp.stack([-limit, limit], -1))
        size, geom_pos, body_pos = self._geom_size, self._geom_pos, self._body_pos
        scale = params.radius_scale[:, None]
        # under warp the bounding sphere and box scale with the wheel: MuJoCo Warp's
        # broadphase culls pairs with them (a wheel larger than its bound would only touch
        # the floor once it had sunk in); MJX's JAX collision does not read them here
        rbound, aabb = m.geom_rbound, m.geom_aabb
        if self.impl == "warp":
            rbound = rbound.at[self._wheel_geoms].multiply(scale)
            aabb = aabb.at[self._wheel_geoms].multiply(
                scale.reshape(*scale.shape, *(1,) * (aabb.ndim - 1))
            )
        if self.fidelity == "fast":
            size = size.at[self._wheel_geoms[:, 0], 0].multiply(params.radius_scale)
        else:  # the whole roller ring scales about the axle: rollers, spheres, capsules
            size = (
                size.at[self._wheel_geoms, 0]
                .multiply(scale)
                .at[self._wheel_geoms, 1]
                .multiply(scale)
            )
            geom_pos = geom_pos.at[self._wheel_geoms].multiply(scale[..., None])
            body_pos = body_pos.at[self._roller_bodies].multiply(scale[..., None])
        return m.replace(
            geom_friction=friction,
            geom_size=size,
            geom_rbound=rbound,
            geom_aabb=aabb,
            geom_pos=geom_pos,
            body_pos=body_pos,
            body_mass=m.body_mass.at[c].set(total),
            body_ipos=m.body_ipos.at[c].set(com),
            body_inertia=m.body_inertia.at[c].set(inertia),
            actuator_gainprm=gain,
            actuator_biasprm=bias,
            actuator_forcerange=frange,
        )


WARP_CONTACTS = {"fast": 2, "reference": 6}
"""Contact capacity per wheel and robot under ``sim.impl = "warp"``, per fidelity: a fast
wheel (a sphere) touches the floor at one point, a reference wheel with two or three of its
roller spheres; twice that leaves headroom for the moments rollers change over."""


def _quiet_solver_limits(model: mjx.Model) -> mjx.Model:
    """MuJoCo Warp prints a line whenever a solve stops at its iteration or line-search
    limit; MJX's JAX implementation stops there silently, and so does this project (the
    limits are set on purpose, SimSpec.iterations). Buffer overflows still print."""
    from mujoco.mjx.third_party.mujoco_warp import OverflowType

    quiet = OverflowType.ALL & ~(OverflowType.ITERATIONS | OverflowType.LS_ITERATIONS)
    impl = dataclasses.replace(model.opt._impl, warn_overflow=int(quiet))
    return model.replace(opt=model.opt.replace(_impl=impl))


__all__ = ["WARP_CONTACTS", "RobotModel"]
