"""The library's sub-packages follow the pipeline: each imports only those before it."""

import ast
from pathlib import Path

import pytest

LIBRARY = Path(__file__).resolve().parent.parent / "mecanum_jax"
ORDER = ("kinematics", "sim", "task", "evaluation", "deploy")


def imported_packages(path: Path) -> set[str]:
    """The ``mecanum_jax`` sub-packages a module imports (at any depth, type-only included)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.ImportFrom) and node.module:
            names = [node.module, *(f"{node.module}.{a.name}" for a in node.names)]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        for name in names:
            parts = name.split(".")
            if parts[0] == "mecanum_jax" and len(parts) > 1 and parts[1] in ORDER:
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
        "compat.py",
        "precision.py",
    ):
        assert not imported_packages(LIBRARY / name), name


def test_the_check_sees_a_violation(tmp_path):
    """The test above can fail: a kinematics module importing the task is caught."""
    bad = tmp_path / "bad.py"
    bad.write_text("from mecanum_jax.task.env import MecanumEnv\nimport mecanum_jax.sim.physics\n")
    assert imported_packages(bad) == {"task", "sim"}
