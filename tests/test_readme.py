"""The README cannot drift from the code: every ```python block runs (in order, in one namespace,
as a reader would paste them), and the page keeps its promises about its own shape."""
import os
import re

import pytest

import nrmicp  # noqa: F401  (required: a missing one fails, not skips)
import pyamg  # noqa: F401  (required: a missing one fails, not skips)

README = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "README.md")


def _text():
    with open(README, encoding="utf-8") as f:
        return f.read()


def python_blocks(text):
    return re.findall(r"^```python\n(.*?)^```", text, flags=re.S | re.M)


def test_readme_has_python_blocks():
    assert len(python_blocks(_text())) >= 3


def test_every_python_block_of_the_readme_runs():
    namespace = {"__name__": "readme"}
    for i, block in enumerate(python_blocks(_text())):
        try:
            exec(compile(block, f"README.md python block {i + 1}", "exec"), namespace)
        except Exception as exc:  # name the block that failed
            raise AssertionError(f"README python block {i + 1} failed: {exc!r}\n{block}") from exc


def test_readme_answers_which_method_and_how_fast_early_and_stays_short():
    lines = _text().splitlines()
    heading = {line: i for i, line in enumerate(lines) if line.startswith("## ")}
    assert heading["## Which method for which problem"] < 150
    assert heading["## How fast: what each digit costs"] < 150
    assert len(lines) <= 470  # the before-stop check warns beyond 470


def test_every_command_the_readme_names_exists():
    text = _text()
    root = os.path.dirname(README)
    for script in set(re.findall(r"python (benchmarks/\w+\.py)", text)):
        assert os.path.exists(os.path.join(root, script)), script
    for image in set(re.findall(r"\]\((docs/[\w.]+\.png)\)", text)):
        assert os.path.exists(os.path.join(root, image)), image
