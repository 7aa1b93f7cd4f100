"""The library's sub-packages follow the pipeline, and the trainer's rooms their order: each
imports only those before it."""

import ast
from pathlib import Path

import pytest

LIBRARY = Path(__file__).resolve().parent.parent / "mecanum_jax"
ORDER = ("kinematics", "sim", "task", "evaluation", "deploy")
TRAINER = LIBRARY.parent / "train"
ROOMS = ("store", "learner", "loop")
"""The trainer's rooms from the ground up; ``cli`` and ``tools`` stand on them side by side."""
TOP_ROOMS = ("cli", "tools")


def imported_packages(
    path: Path, top: str = "mecanum_jax", packages: tuple[str, ...] = ORDER
) -> set[str]:
    """The ``top`` sub-packages among ``packages`` a module imports (at any depth, type-only
    included)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.ImportFrom) and node.module:
            names = [node.module, *(f"{node.module}.{a.name}" for a in node.names)]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        for name in names:
            parts = name.split(".")
            if parts[0] == top and len(parts) > 1 and parts[1] in packages:
                found.add(parts[1])
    return found


@pytest.mark.parametrize("package", ORDER)
def test_sub_package_imports_only_earlier_ones(package):
    allowed = set(ORDER[: ORDER.index(package) + 1])
    for path in sorted((LIBRARY / package).glob("*.py")):
        later = imported_packages(path) - allowed
        assert not later, f"{path.relative_to(LIBRARY)} imports {sorted(later)}"


def test_shared_modules_import_no_sub_package():
    """config, _checks and the other shared modules sit below every sub-package."""
    for name in (
        "config.py",
        "_checks.py",
        "_lazy.py",
        "_quiet_mjx.py",
        "precision.py",
    ):
        assert not imported_packages(LIBRARY / name), name


@pytest.mark.parametrize("room", ROOMS + TOP_ROOMS)
def test_trainer_room_imports_only_lower_ones(room):
    """store <- learner <- loop <- cli, tools: no room imports one above it, and the two top
    rooms do not import each other."""
    below = ROOMS if room in TOP_ROOMS else ROOMS[: ROOMS.index(room)]
    paths = sorted((TRAINER / room).glob("*.py"))
    assert paths, room
    for path in paths:
        higher = imported_packages(path, "train", ROOMS + TOP_ROOMS) - {room, *below}
        assert not higher, f"{path.relative_to(TRAINER)} imports {sorted(higher)}"


def test_trainer_shared_modules_import_no_room():
    """The trainer's modules outside its rooms (its config) sit below every room."""
    for path in sorted(TRAINER.glob("*.py")):
        assert not imported_packages(path, "train", ROOMS + TOP_ROOMS), path.name


def test_the_check_sees_a_violation(tmp_path):
    """The test above can fail: a kinematics module importing the task is caught."""
    bad = tmp_path / "bad.py"
    bad.write_text("from mecanum_jax.task.env import MecanumEnv\nimport mecanum_jax.sim.physics\n")
    assert imported_packages(bad) == {"task", "sim"}


def test_no_python_file_is_over_400_lines():
    """The house rule: a file that grows past 400 lines is split into the rooms it holds."""
    root = LIBRARY.parent
    files = [
        p for d in ("mecanum_jax", "train", "tests", "scripts") for p in (root / d).rglob("*.py")
    ]
    assert len(files) > 100
    long = {
        str(p.relative_to(root)): n for p in files if (n := len(p.read_text().splitlines())) > 400
    }
    assert not long, f"over 400 lines: {long}"
