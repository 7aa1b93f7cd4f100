"""The main job (the kinematics demo) runs and prints the six modes."""

from mecanum_jax import demo


def test_demo_prints_six_modes(capsys):
    demo.main(["--robot", "o_rectangle", "--speed", "0.5"])
    out = capsys.readouterr().out
    for label in ("forward", "backward", "diagonal", "lateral", "clockwise", "counter"):
        assert label in out
    assert "Jacobian rank 3" in out


def test_demo_rejects_bad_speed(capsys):
    assert demo.main(["--speed", "-1"]) == 2
    assert "--speed = -1.0" in capsys.readouterr().err
