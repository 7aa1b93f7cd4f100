"""The README's Python examples run as written."""

import re
from pathlib import Path

import pytest

README = (Path(__file__).resolve().parent.parent / "README.md").read_text()
BLOCKS = re.findall(r"```python\n(.*?)```", README, flags=re.S)
EXAMPLES = 2
"""The README's ```python blocks (the kinematics, and odometry with the limits); one
lost, or a fence this pattern no longer matches, fails here rather than going untested."""


def test_readme_has_its_python_examples():
    """The examples below are parametrized over the README's blocks: with fewer, the
    missing ones would not run and nothing would fail; this does."""
    assert len(BLOCKS) >= EXAMPLES, (
        f"README.md has {len(BLOCKS)} ```python blocks, expected at least {EXAMPLES}"
    )


@pytest.mark.parametrize("index", range(len(BLOCKS)))
def test_readme_example_runs(index):
    exec(compile(BLOCKS[index], f"README.md[python block {index}]", "exec"), {})
