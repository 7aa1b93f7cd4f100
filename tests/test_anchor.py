"""``ppo.anchor``: no yaw correction where the residual's base is exact (steady no-yaw
commands on the nominal robot; mecanum_jax/task/anchor.py, train/losses.py)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import pytest
from brax.training import types
from brax.training.acme import running_statistics
from test_losses import OBS, _Shapes

from mecanum_jax.config import ConfigError
from mecanum_jax.task import EnvConfig, FeedbackConfig, MecanumEnv, RandomizationConfig
from mecanum_jax.task.anchor import YAW, base_exact
from train.config import TrainConfig, load_train_config, parse_train_config
from train.losses import AnchorConfig, anchor_loss, ppo_loss_with_terms, state_extras
from train.state import make_networks

HOLD = FeedbackConfig(hold_s=0.4)  # 20 control periods


def _env(randomization: RandomizationConfig) -> MecanumEnv:
    cfg = EnvConfig(
        residual_space="twist", residual_base="feedback", feedback=HOLD, randomization=randomization
    )
    return MecanumEnv(cfg)


def _with(info, command, age):
    return {**info, "command": jnp.asarray(command, jnp.float32), "command_age": jnp.asarray(age)}


def test_the_mask_marks_steady_no_yaw_commands_on_the_nominal_robot_only():
    nominal = _env(RandomizationConfig(enabled=True, nominal_share=1.0))
    info = jax.jit(nominal.reset)(jax.random.PRNGKey(0)).info
    assert float(base_exact(nominal, _with(info, [0.4, 0.2, 0.0], 20))) == 1.0
    assert float(base_exact(nominal, _with(info, [0.0, 0.0, 0.0], 30))) == 1.0  # a stop
    assert float(base_exact(nominal, _with(info, [0.4, 0.2, 0.0], 19))) == 0.0  # transient
    assert float(base_exact(nominal, _with(info, [0.4, 0.2, 0.5], 40))) == 0.0  # a turn
    randomized = _env(RandomizationConfig(enabled=True, nominal_share=0.0))
    info = jax.jit(randomized.reset)(jax.random.PRNGKey(0)).info
    assert float(base_exact(randomized, _with(info, [0.4, 0.2, 0.0], 40))) == 0.0


def test_state_extras_carry_the_mask_only_when_the_anchor_is_on():
    env = _env(RandomizationConfig(enabled=True, nominal_share=0.5))
    batch = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(1), 64))
    info = {**batch.info, "command": batch.info["command"].at[:, YAW].set(0.0),
            "command_age": jnp.full((64,), 25)}  # fmt: skip
    off = state_extras(env, info, batch.info, AnchorConfig())
    assert set(off) == {"truncation"}
    on = state_extras(env, info, batch.info, AnchorConfig(weight=1.0))
    mask = on["anchor"]
    assert mask.shape == (64,)
    assert 0 < float(mask.sum()) < 64  # about half the robots are nominal
    one = jax.tree.map(lambda x: x[int(jnp.argmax(mask))], info)
    assert float(base_exact(env, one)) == 1.0


def test_the_loss_is_the_masked_mean_of_the_yaw_part():
    action = jnp.asarray([[0.1, 0.2, 0.3], [0.5, 0.5, -0.6], [1.0, 1.0, 2.0]])
    assert float(anchor_loss(action, jnp.asarray([0.0, 0.0, 0.0]), YAW)) == 0.0
    got = anchor_loss(action, jnp.asarray([1.0, 1.0, 0.0]), YAW)
    assert float(got) == pytest.approx((0.09 + 0.36) / 2)
    # the translation parts never count
    flat = action.at[:, :YAW].set(0.0)
    assert float(anchor_loss(flat, jnp.asarray([1.0, 1.0, 0.0]), YAW)) == pytest.approx(float(got))


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
                "state_extras": {"truncation": jnp.zeros((b, t)), "anchor": jnp.ones((b, t))}},
    )  # fmt: skip

    class P:  # what the loss reads of Brax's PPO parameters
        def __init__(self):
            self.policy, self.value = policy, value

    kwargs = dict(ppo_network=networks, smoothness=cfg.ppo.smoothness, entropy_cost=0.0)
    with jax.numpy_rank_promotion("allow"):
        base, m0 = ppo_loss_with_terms(P(), normalizer, data, key, **kwargs)
        with_term, m1 = ppo_loss_with_terms(P(), normalizer, data, key, anchor_weight=10.0,
                                            **kwargs)  # fmt: skip
    assert "anchor" not in m0
    assert float(m1["anchor"]) > 0
    assert float(with_term) == pytest.approx(float(base) + 10.0 * float(m1["anchor"]), rel=1e-5)


def test_bad_anchor_settings_name_the_field():
    with pytest.raises(ConfigError, match=r"ppo\.anchor\.weight = -1"):
        AnchorConfig(weight=-1.0).validate()
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
    assert gpu.ppo.anchor.weight == 100.0
