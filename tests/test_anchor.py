"""``ppo.anchor``: no correction where the residual's base is exact (the yaw of steady no-yaw
commands on the nominal robot, and with spins every component of its steady spins and
stops; mecanum_jax/task/anchor.py, train/learner/losses.py)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import pytest
from brax.training import types
from brax.training.acme import running_statistics
from test_losses import OBS, _Shapes

from mecanum_jax.config import ConfigError
from mecanum_jax.kinematics import limits
from mecanum_jax.task import EnvConfig, FeedbackConfig, MecanumEnv, RandomizationConfig
from mecanum_jax.task.anchor import YAW, exact_components, is_nominal
from train.config import TrainConfig
from train.config_loading import load_train_config, parse_train_config
from train.learner.losses import anchor_loss, ppo_loss_with_terms, state_extras
from train.learner.state import make_networks
from train.loss_config import AnchorConfig

HOLD = FeedbackConfig(hold_s=0.4)  # 20 control periods


def _env(randomization: RandomizationConfig) -> MecanumEnv:
    cfg = EnvConfig(
        residual_space="twist", residual_base="feedback", feedback=HOLD, randomization=randomization
    )
    return MecanumEnv(cfg)


@pytest.fixture(scope="module")
def robots():
    """An environment whose robots are nominal half the time, and 64 of them reset (one
    compiled reset for the module): ``(env, batch)``."""
    env = _env(RandomizationConfig(enabled=True, nominal_share=0.5))
    return env, jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(1), 64))


def _one(robots, nominal: bool):
    """The info of the batch's first nominal (or first randomized) robot."""
    env, batch = robots
    which = jax.vmap(lambda i: is_nominal(env.constants, i))(batch.info) == nominal
    assert bool(which.any())
    index = int(jnp.argmax(which))
    return jax.tree.map(lambda x: x[index], batch.info)


def _with(info, command, age):
    return {**info, "command": jnp.asarray(command, jnp.float32), "command_age": jnp.asarray(age)}


def _hold(env):
    return env.config.feedback.hold_steps(env.config.control_dt)


def _mask(env, info, command, age, spins=False, translations=False):
    info = _with(info, command, age)
    mask = exact_components(env.constants, info, _hold(env), spins, translations)
    return [float(x) for x in mask]


def test_the_mask_marks_the_yaw_of_steady_no_yaw_commands_on_the_nominal_robot_only(robots):
    nominal, info = robots[0], _one(robots, True)
    assert _mask(nominal, info, [0.4, 0.2, 0.0], 20) == [0.0, 0.0, 1.0]
    assert _mask(nominal, info, [0.0, 0.0, 0.0], 30) == [0.0, 0.0, 1.0]  # a stop
    assert _mask(nominal, info, [0.4, 0.2, 0.0], 19) == [0.0, 0.0, 0.0]  # transient
    assert _mask(nominal, info, [0.4, 0.2, 0.5], 40) == [0.0, 0.0, 0.0]  # a turn
    assert _mask(nominal, info, [0.0, 0.0, 2.0], 40) == [0.0, 0.0, 0.0]  # a spin: not without
    randomized = _one(robots, False)
    assert _mask(nominal, randomized, [0.4, 0.2, 0.0], 40) == [0.0, 0.0, 0.0]


def test_with_spins_the_mask_marks_every_component_of_steady_spins_within_reach_and_stops(
    robots,
):
    nominal, info = robots[0], _one(robots, True)
    reach = float(limits.max_speed(nominal.geometry, jnp.array([0.0, 0.0, 1.0]), nominal.max_rates))
    assert _mask(nominal, info, [0.0, 0.0, 0.5 * reach], 20, True) == [1.0, 1.0, 1.0]
    assert _mask(nominal, info, [0.0, 0.0, -0.8 * reach], 20, True) == [1.0, 1.0, 1.0]
    assert _mask(nominal, info, [0.0, 0.0, 0.0], 20, True) == [1.0, 1.0, 1.0]  # a stop
    assert _mask(nominal, info, [0.0, 0.0, 1.2 * reach], 40, True) == [0.0, 0.0, 0.0]  # beyond
    assert _mask(nominal, info, [0.0, 0.0, 0.5 * reach], 19, True) == [0.0, 0.0, 0.0]  # transient
    assert _mask(nominal, info, [0.4, 0.2, 0.0], 20, True) == [0.0, 0.0, 1.0]  # translation
    assert _mask(nominal, info, [0.4, 0.0, 0.5], 20, True) == [0.0, 0.0, 0.0]  # a turn
    randomized = _one(robots, False)
    assert _mask(nominal, randomized, [0.0, 0.0, 0.5 * reach], 40, True) == [0.0, 0.0, 0.0]


def test_with_translations_the_mask_marks_every_component_of_steady_translations_within_reach(
    robots,
):
    nominal, info = robots[0], _one(robots, True)
    direction = jnp.array([0.6, 0.8, 0.0])
    reach = float(limits.max_speed(nominal.geometry, direction, nominal.max_rates))
    inside, beyond = (list(map(float, f * reach * direction)) for f in (0.7, 1.2))
    assert _mask(nominal, info, inside, 20, translations=True) == [1.0, 1.0, 1.0]
    assert _mask(nominal, info, beyond, 40, translations=True) == [0.0, 0.0, 1.0]  # beyond
    assert _mask(nominal, info, inside, 19, translations=True) == [0.0, 0.0, 0.0]  # transient
    assert _mask(nominal, info, [0.0, 0.0, 0.0], 20, translations=True) == [1.0, 1.0, 1.0]
    assert _mask(nominal, info, [0.0, 0.0, 1.0], 20, translations=True) == [0.0, 0.0, 0.0]
    assert _mask(nominal, info, [0.3, 0.0, 0.5], 20, translations=True) == [0.0, 0.0, 0.0]
    assert _mask(nominal, info, [0.0, 0.0, 1.0], 20, True, True) == [1.0, 1.0, 1.0]  # both
    randomized = _one(robots, False)
    assert _mask(nominal, randomized, inside, 40, translations=True) == [0.0, 0.0, 0.0]


def test_state_extras_carry_the_mask_only_when_the_anchor_is_on(robots):
    env, batch = robots
    info = {**batch.info, "command": batch.info["command"].at[:, :YAW].set(0.0),
            "command_age": jnp.full((64,), 25)}  # fmt: skip
    off = state_extras(env, info, batch.info, AnchorConfig(weight=0.0))
    assert set(off) == {"truncation"}
    yaw_only = state_extras(
        env, info, batch.info, AnchorConfig(weight=1.0, spins=False, translations=False)
    )["anchor"]
    spins = state_extras(
        env, info, batch.info, AnchorConfig(weight=1.0, spins=True, translations=False)
    )["anchor"]
    assert yaw_only.shape == spins.shape == (64, 3)
    nominal = jax.vmap(lambda i: is_nominal(env.constants, i))(info)
    assert 0 < int(nominal.sum()) < 64  # about half the robots are nominal
    # without spins=True only the stops' yaw is marked; marks follow the robot: none on
    # the randomized ones
    stop = nominal & (info["command"][:, YAW] == 0.0)
    assert float(yaw_only[:, :YAW].sum()) == 0.0
    assert bool(jnp.all(yaw_only[:, YAW] == stop))
    assert float(spins[~nominal].sum()) == 0.0
    assert float(spins.sum()) > 0
    one = jax.tree.map(lambda x: x[int(jnp.argmax(spins[:, YAW]))], info)
    assert [float(x) for x in exact_components(env.constants, one, _hold(env), True)] == [1.0] * 3


def test_the_loss_is_the_masked_mean_over_states_and_components():
    action = jnp.asarray([[0.1, 0.2, 0.3], [0.5, 0.5, -0.6], [1.0, 1.0, 2.0]])
    assert float(anchor_loss(action, jnp.zeros((3, 3)))) == 0.0
    yaw = jnp.asarray([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]])
    assert float(anchor_loss(action, yaw)) == pytest.approx((0.09 + 0.36) / 2)
    every = jnp.asarray([[1.0, 1.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]])
    assert float(anchor_loss(action, every)) == pytest.approx((0.01 + 0.04 + 0.09 + 0.36) / 4)


def test_the_ppo_loss_adds_the_weighted_term():
    cfg = TrainConfig()
    networks = make_networks(_Shapes(), cfg)  # type: ignore[arg-type]
    key = jax.random.PRNGKey(2)
    policy = networks.policy_network.init(key)
    value = networks.value_network.init(key)
    spec = {k: jax.ShapeDtypeStruct((v,), jnp.float32) for k, v in OBS.items()}
    normalizer = running_statistics.init_state(spec)
    b, t = 4, 5
    obs = {k: jax.random.normal(key, (b, t, v)) for k, v in OBS.items()}
    raw = jax.random.normal(jax.random.PRNGKey(3), (b, t, 3))
    with jax.numpy_rank_promotion("allow"):
        dist = networks.policy_network.apply(normalizer, policy, obs)
    data = types.Transition(
        observation=obs, action=jnp.tanh(raw), reward=jnp.ones((b, t)),
        discount=jnp.ones((b, t)), next_observation=obs,
        extras={"policy_extras": {"raw_action": raw, "log_prob": jnp.zeros((b, t)),
                                  "distribution_params": dist},
                "state_extras": {"truncation": jnp.zeros((b, t)), "anchor": jnp.ones((b, t, 3))}},
    )  # fmt: skip

    class P:  # what the loss reads of Brax's PPO parameters
        def __init__(self):
            self.policy, self.value = policy, value

    kwargs = dict(ppo_network=networks, smoothness=cfg.ppo.smoothness, entropy_cost=0.0)

    @jax.jit  # one program each, as the learner runs it, instead of operation by operation
    def both(data):
        base = ppo_loss_with_terms(P(), normalizer, data, key, **kwargs)
        return base, ppo_loss_with_terms(P(), normalizer, data, key, anchor_weight=10.0, **kwargs)

    with jax.numpy_rank_promotion("allow"):
        (base, m0), (with_term, m1) = both(data)
    assert "anchor" not in m0
    assert float(m1["anchor"]) > 0
    assert float(with_term) == pytest.approx(float(base) + 10.0 * float(m1["anchor"]), rel=1e-5)


def test_bad_anchor_settings_name_the_field():
    with pytest.raises(ConfigError, match=r"ppo\.anchor\.weight = -1"):
        AnchorConfig(weight=-1.0).validate()
    with pytest.raises(ConfigError, match=r"ppo\.anchor\.translations = 1: must be true or"):
        AnchorConfig(translations=1).validate()  # type: ignore[arg-type]
    wheel = {"env": {"residual_space": "wheel"}, "ppo": {"anchor": {"weight": 1.0}}}
    with pytest.raises(ConfigError, match=r"ppo\.anchor\.weight = 1\.0.*twist"):
        parse_train_config(wheel, "test")
    no_nominal = {
        "env": {
            "residual_space": "twist",
            "randomization": {"enabled": True, "nominal_share": 0.0},
        },
        "ppo": {"anchor": {"weight": 1.0}},
    }
    with pytest.raises(ConfigError, match=r"ppo\.anchor\.weight = 1\.0.*nominal_share"):
        parse_train_config(no_nominal, "test")
    gpu = load_train_config("gpu")  # as shipped: a twist residual with nominal robots
    assert gpu.ppo.anchor.weight == 1000.0
    assert gpu.ppo.anchor.spins
    assert gpu.ppo.anchor.translations
