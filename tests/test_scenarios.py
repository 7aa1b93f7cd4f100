"""The evaluation's scenarios: the default set, the scripted sequences, episode preparation
and bad scenario files."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mecanum_jax.config import ConfigError
from mecanum_jax.evaluation import episodes, scenarios
from mecanum_jax.evaluation.traces import intended_poses
from mecanum_jax.kinematics import limits, singularity
from mecanum_jax.kinematics.modes import SIX_MODES
from mecanum_jax.task import EnvConfig, MecanumEnv

PATHS = ["figure_eight", "zigzag", "bursts", "stop_and_go", "square", "slalom", "spin_then_go"]
NOMINAL_FLOOR = {"friction": [0.98, 1.02]}
"""What the shipped scenario files put under every scenario ([defaults] randomization)."""


def test_default_scenarios_are_the_issue_list(shipped):
    assert shipped.names == [
        "nominal",
        "six_modes",
        "slippery",
        "payload",
        "radius_error",
        "weak_motors",
        "sensor_noise",
        "singular_pass",
        *PATHS,  # configs/eval/paths.toml, included
    ]
    for s in shipped.scenarios:
        assert s.description, s.name
    by = {s.name: s for s in shipped.scenarios}
    assert by["nominal"].randomization == NOMINAL_FLOOR
    assert by["nominal"].noise.scale == 0
    assert by["slippery"].randomization_config(1.0).friction[1] < 0.5
    assert by["weak_motors"].command_config(EnvConfig().commands).p_beyond >= 0.5
    assert by["sensor_noise"].randomization["latency_steps"] == [2, 2]
    assert by["six_modes"].scripted
    assert by["singular_pass"].scripted
    assert not by["payload"].scripted


def test_six_modes_sequence_follows_seed_000(eval_env, shipped):
    sc = shipped.select(["six_modes"]).scenarios[0]
    cmds = episodes.scripted_commands(eval_env, sc)
    per = round(sc.commands.segment_s / eval_env.config.control_dt)
    gap = round(sc.commands.pause_s / eval_env.config.control_dt)
    for i, (_, unit, _) in enumerate(SIX_MODES.values()):
        seg = cmds[i * (per + gap) : i * (per + gap) + per]
        assert np.all(seg == seg[0])
        direction = seg[0] / np.linalg.norm(seg[0])
        np.testing.assert_allclose(direction, np.asarray(unit) / np.linalg.norm(unit), atol=1e-6)
        assert np.all(cmds[i * (per + gap) + per : (i + 1) * (per + gap)] == 0)
    assert np.all(cmds[6 * (per + gap) :] == 0)  # then stop


def test_singular_pass_drags_two_wheels_and_is_closed(eval_env, shipped):
    sc = shipped.select(["singular_pass"]).scenarios[0]
    cmds = episodes.scripted_commands(eval_env, sc)
    moving = cmds[np.linalg.norm(cmds, axis=-1) > 0]
    assert len(moving) > 0
    still = np.asarray(
        singularity.singular_wheels(eval_env.geometry, jnp.asarray(moving), tol=1e-5)
    )
    assert np.all(still.sum(axis=-1) == 2)  # two wheels only dragged at every moving step
    path = intended_poses(cmds[None], eval_env.config.control_dt)[0]
    np.testing.assert_allclose(path[-1], 0.0, atol=1e-5)  # out and back: a closed sequence
    assert np.max(np.linalg.norm(path[:, :2], axis=-1)) > 0.5


def test_episodes_do_not_follow_the_targets_command_mix(eval_env, shipped):
    """A policy trained on another episode mix is judged on the same episodes."""
    from mecanum_jax.task import CommandConfig, RandomizationConfig

    other = MecanumEnv(
        dataclasses.replace(
            eval_env.config,
            commands=CommandConfig(p_zero=0.0, p_translation=1.0, resample_max_s=9.0),
            randomization=RandomizationConfig(nominal_share=0.5),
        )
    )
    sc = shipped.select(["nominal"], 4, 3.0).scenarios[0]
    a, b = episodes.prepare(eval_env, sc), episodes.prepare(other, sc)
    assert np.any(np.asarray(a.commands)[..., 2] != 0)  # spins: not the other's mix
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_prepare_is_seeded_and_applies_the_physics(eval_env, shipped):
    sets = shipped.select(["slippery", "payload", "radius_error", "weak_motors", "sensor_noise"])
    by = {s.name: episodes.prepare(eval_env, s) for s in sets.scenarios}
    again = episodes.prepare(eval_env, sets.scenarios[0])
    for a, b in zip(jax.tree.leaves(again), jax.tree.leaves(by["slippery"]), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    f = np.asarray(by["slippery"].params.friction)
    assert f.min() >= 0.12 * 0.9 - 1e-6
    assert f.max() <= 0.2 * 1.1 + 1e-6
    p = by["payload"].params
    assert np.all(np.asarray(p.payload_mass) >= 2.5)
    np.testing.assert_allclose(np.asarray(p.payload_com)[:, :2], [[0.06, 0.04]] * 32, atol=1e-6)
    r = np.asarray(by["radius_error"].params.radius_scale)
    assert r.max() < 1.0
    assert r.min() > 0.93
    nominal_torque = eval_env.robot.nominal_params().torque_limit
    np.testing.assert_allclose(by["weak_motors"].params.torque_limit[0], 0.5 * nominal_torque)
    assert np.all(np.asarray(by["sensor_noise"].latency) == 2)
    np.testing.assert_allclose(by["sensor_noise"].noise_std[0], 2 * eval_env.noise_std())
    # different scenarios draw different episodes from the same seed
    assert not np.array_equal(by["payload"].commands, by["radius_error"].commands)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[scenarios.a]\nbogus = 1", "scenarios.a.bogus = 1: unknown key"),
        (
            "[scenarios.a.randomization]\nfriction = [0.5, 0.2]",
            "scenarios.a.randomization.friction = [0.5, 0.2]: lower bound above upper",
        ),
        ('[scenarios.a.commands]\nkind = "zigzag"', "scenarios.a.commands.kind = 'zigzag'"),
        (
            '[scenarios.a]\nseconds = 2.0\n[scenarios.a.commands]\nkind = "sequence"\n'
            "sequence = [[0.5, 0, 0, 3.0]]",
            "scenarios.a.commands.sequence = '3.0 s': longer than the episode",
        ),
        (
            '[scenarios.a.commands]\nkind = "sequence"\nsequence = [[3.0, 0, 0, 1.0]]',
            'scenarios.a.commands.sequence[0] = [3.0, 0.0, 0.0, 1.0]: units = "reach"',
        ),
        ('[scenarios.a.commands]\nkind = "six_modes"\np_zero = 0.5', "scenarios.a.commands.p_zero"),
        ("[scenarios.Bad]\n", "scenarios.Bad = 'Bad': scenario names are lower_snake_case"),
        ("[scenarios.a]\nepisodes = 0", "scenarios.a.episodes = 0: must be in [1, 4096]"),
        ("[scenarios.a.noise]\nscale = -1.0", "scenarios.a.noise.scale = -1.0: must be >= 0"),
        ("[defaults]\nseed = 'x'\n[scenarios.a]", "defaults.seed = 'x': expected an integer"),
        ("[defaults]\n", "expected at least one [scenarios.<name>] table"),
        ("[defaults]\nbogus = 1\n[scenarios.a]", "defaults.bogus = 1: unknown key"),
        (
            "[defaults.randomization]\nfloor = 1.0\n[scenarios.a]",
            "defaults.randomization.floor = 1.0: unknown key",
        ),
        (
            "[defaults.randomization]\nfriction = [0.5, 0.2]\n[scenarios.a]",
            "scenarios.a.randomization.friction = [0.5, 0.2]: lower bound above upper",
        ),
        ("[scenarios.a.randomization]\nenabled = false", "scenarios.a.randomization.enabled"),
    ],
)
def test_bad_scenario_files_name_the_field(tmp_path, text, message):
    path = tmp_path / "s.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        scenarios.load_scenarios(path)
    assert message in str(err.value)


def test_scenario_selection_errors(shipped):
    with pytest.raises(ConfigError, match=r"scenario 'icy': not in .* available: \['nominal'"):
        shipped.select(["icy"])
    with pytest.raises(ConfigError, match="episodes = 0"):
        shipped.select(episodes=0)
    with pytest.raises(ConfigError, match="no such scenario file"):
        scenarios.load_scenarios("nonexistent")


def test_si_commands_beyond_twice_the_reach_are_named_when_played(eval_env, tmp_path):
    """units = "si" cannot be bounded in the file (it names no robot): the robot that plays
    it refuses a segment beyond twice its reach, as units = "reach" refuses beyond 2."""
    path = tmp_path / "si.toml"
    seq = "[[0.5, 0.0, 0.0, 1.0], [0.0, 0.0, 1e9, 1.0]]"
    path.write_text(
        f'[scenarios.a]\nseconds = 2.0\ncommands = {{ kind = "sequence", units = "si", '
        f"sequence = {seq} }}\n"
    )
    sc = scenarios.load_scenarios(path).scenarios[0]
    with pytest.raises(ConfigError, match=r"scenarios\.a\.commands\.sequence\[1\] = .*twice"):
        episodes.scripted_commands(eval_env, sc)
    within = dataclasses.replace(
        sc, commands=dataclasses.replace(sc.commands, sequence=((0.5, 0.0, 0.0, 2.0),))
    )
    np.testing.assert_allclose(episodes.scripted_commands(eval_env, within)[0], [0.5, 0.0, 0.0])


def test_singular_pass_needs_a_layout_with_singular_directions(shipped):
    env3 = MecanumEnv(EnvConfig(robot="centripetal3"))
    sc = shipped.select(["singular_pass"]).scenarios[0]
    with pytest.raises(ConfigError, match="has no singular directions"):
        episodes.scripted_commands(env3, sc)


def test_reach_split_keeps_commands_on_their_side_of_the_reach(eval_env):
    """configs/eval/reach.toml: its *within* episodes never command beyond the wheels'
    reach and its *beyond* episodes always do, away from stops (a stop is within reach)."""

    split = scenarios.load_scenarios("reach").select(["nominal_within", "nominal_beyond"], 8, 4.0)
    c = eval_env.constants
    for sc in split.scenarios:
        cmd = np.asarray(episodes.prepare(eval_env, sc).commands).reshape(-1, 3)
        cmd = cmd[np.any(cmd != 0.0, axis=-1)]
        assert len(cmd), sc.name
        beyond = np.asarray(limits.saturation(c.geometry, cmd, c.max_rates)) > 1.0 + 1e-6
        assert np.all(beyond) if sc.name.endswith("beyond") else not np.any(beyond), sc.name


def test_latency_split_varies_noise_and_latency_alone():
    """configs/eval/latency.toml: each scenario is the nominal robot at the noise scale and
    latency its name gives (noise<k>_lat<l>), on the tuning seed, so settling can be split
    between the two."""
    split = scenarios.load_scenarios("latency")
    tuning_seed = scenarios.load_scenarios("tuning").scenarios[0].seed
    assert len(split.scenarios) == 5
    for sc in split.scenarios:
        assert sc.seed == tuning_seed, sc.name
        noise, lat = sc.name.removeprefix("noise").split("_lat")
        assert sc.noise.scale == float(noise), sc.name
        rand = sc.randomization_config(1.0)
        assert tuple(rand.latency_steps) == (int(lat), int(lat)), sc.name
        assert set(sc.randomization) <= {"latency_steps", "friction"}, sc.name
        assert sc.randomization["friction"] == NOMINAL_FLOOR["friction"], sc.name
        assert not sc.mix, sc.name


def test_starts_are_single_translations_from_rest_at_the_named_speed():
    """configs/eval/starts.toml: each scenario is the nominal robot with the training's sensor
    noise, one pure translation from rest at the fraction of the reach its name gives
    (direction_<percent>), then at least 1.5 s of stop, on the tuning seed."""
    starts = scenarios.load_scenarios("starts")
    tuning_seed = scenarios.load_scenarios("tuning").scenarios[0].seed
    directions = {"forward": (1, 0), "backward": (-1, 0), "right": (0, -1)}
    assert {sc.name.split("_")[0] for sc in starts.scenarios} == set(directions)
    for sc in starts.scenarios:
        where, percent = sc.name.split("_")
        assert sc.seed == tuning_seed, sc.name
        assert sc.randomization == NOMINAL_FLOOR, sc.name
        assert not sc.mix, sc.name
        assert sc.noise.scale == 1.0, sc.name
        ((vx, vy, wz, seconds),) = sc.commands.sequence
        dx, dy = directions[where]
        assert (vx, vy, wz) == pytest.approx((dx * int(percent) / 100, dy * int(percent) / 100, 0))
        assert sc.seconds - seconds >= 1.5, sc.name


def test_an_included_file_keeps_its_own_defaults_and_names_are_unique(tmp_path):
    from mecanum_jax.evaluation.scenarios import load_scenarios

    paths = load_scenarios("paths")
    assert paths.names == PATHS
    assert all(s.scripted for s in paths.scenarios)
    by = {s.name: s for s in load_scenarios("default").scenarios}
    assert by["zigzag"].seed == paths.scenarios[1].seed != by["nominal"].seed
    (tmp_path / "a.toml").write_text(
        'include = ["paths"]\n[scenarios.zigzag]\ndescription = "a second zigzag"\n'
    )
    with pytest.raises(ConfigError, match="scenario 'zigzag' twice"):
        load_scenarios(tmp_path / "a.toml")
    (tmp_path / "b.toml").write_text(
        f'include = ["{tmp_path / "b.toml"}"]\n[scenarios.x]\ndescription = "x"\n'
    )
    with pytest.raises(ConfigError, match="includes itself"):
        load_scenarios(tmp_path / "b.toml")


def test_dashes_are_the_nominal_robot_on_the_tuning_seed():
    """configs/eval/dashes.toml chooses in the reference roller model: the nominal robot with
    the training's sensor noise, on the tuning seed (no held-out evaluation plays it), each
    a straight dash or cruise from rest with no turn, standing at its end."""
    dashes = scenarios.load_scenarios("dashes")
    tuning_seed = scenarios.load_scenarios("tuning").scenarios[0].seed
    assert dashes.names == ["tuning_dash", "tuning_dash_side", "tuning_cruise"]
    for sc in dashes.scenarios:
        assert sc.seed == tuning_seed, sc.name
        assert sc.randomization == NOMINAL_FLOOR, sc.name
        assert not sc.mix, sc.name
        assert sc.noise.scale == 1.0, sc.name
        legs = sc.commands.sequence
        assert all(wz == 0.0 for _, _, wz, _ in legs), sc.name
        assert sc.seconds - sum(s for *_, s in legs) >= 1.0, sc.name


def test_every_scripted_floor_is_jittered_so_a_blind_controller_plays_many_episodes(
    eval_env, tmp_path
):
    """A ``[defaults]`` randomization lies under each scenario's own, key by key; the shipped
    files draw every floor within 2% of the nominal friction, so that a controller that
    ignores the sensors (``analytic``) does not play one chaotic trajectory 64 times."""
    for name in ("tuning", "default", "paths", "starts", "dashes", "latency", "reach"):
        for sc in scenarios.load_scenarios(name).scenarios:
            if "randomized" in sc.name or "slippery" in sc.name:
                continue  # its own floors
            assert sc.randomization["friction"] == NOMINAL_FLOOR["friction"], (name, sc.name)
    weave = scenarios.load_scenarios("tuning").select(["tuning_weave"]).scenarios[0]
    f = np.asarray(episodes.prepare(eval_env, weave).params.friction)
    assert 0.98 - 1e-6 <= f.min() < f.max() <= 1.02 + 1e-6
    assert len(np.unique(f)) == len(f)  # every episode its own floor
    (tmp_path / "s.toml").write_text(
        "[defaults.randomization]\nfriction = [0.9, 1.1]\npayload_mass = [1.0, 2.0]\n"
        "[scenarios.a]\n[scenarios.b.randomization]\nfriction = [0.2, 0.3]\n"
    )
    a, b = scenarios.load_scenarios(tmp_path / "s.toml").scenarios
    assert a.randomization == {"friction": [0.9, 1.1], "payload_mass": [1.0, 2.0]}
    assert b.randomization == {"friction": [0.2, 0.3], "payload_mass": [1.0, 2.0]}


def test_stress_scenarios_each_leave_the_training_distribution(eval_env):
    """configs/eval/stress.toml: the training's sensor noise on the tuning seed, each scenario
    past the shipped recipe's training in a way it names: latency, payload or grip above
    its range, or legs shorter than its shortest hold; the fast slalom beyond the reach."""
    from train.config_loading import load_train_config

    trained = load_train_config("gpu").env
    r = trained.randomization
    stress = scenarios.load_scenarios("stress")
    tuning_seed = scenarios.load_scenarios("tuning").scenarios[0].seed
    for sc in stress.scenarios:
        assert sc.seed == tuning_seed, sc.name
        assert sc.noise.scale == 1.0, sc.name
        rand = sc.randomization_config(1.0)
        past = {
            "latency": rand.latency_steps[0] > r.latency_steps[1],
            "load": rand.payload_mass[0] > r.payload_mass[1],
            "grip": rand.friction[0] > r.friction[1],
            "short": sc.scripted
            and min(leg[3] for leg in sc.commands.sequence) < trained.commands.resample_min_s,
        }
        assert any(past.values()), sc.name
    slalom = stress.select(["fast_slalom"], 2, 4.0).scenarios[0]
    cmd = np.asarray(episodes.prepare(eval_env, slalom).commands).reshape(-1, 3)
    cmd = cmd[np.any(cmd != 0.0, axis=-1)]
    c = eval_env.constants
    assert np.all(np.asarray(limits.saturation(c.geometry, cmd, c.max_rates)) > 1.0)
