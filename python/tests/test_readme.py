"""The README's Python examples run as written: each ```python block of its "## Python" section,
saved as a script and run from the repository root (as a reader would)."""

import os
import re
import subprocess
import sys

import pytest

from conftest import REPO

README = os.environ.get("RAYPICK_README", str(REPO / "README.md"))


def python_blocks():
    text = open(README, encoding="utf-8").read()
    section = re.search(r"^## Python\n(.*?)(?=^## |\Z)", text, re.S | re.M)
    assert section, f"{README} has no '## Python' section"
    blocks = re.findall(r"^```python\n(.*?)^```", section.group(1), re.S | re.M)
    assert len(blocks) >= 2, "the Python section should show a pick example and a Dask example"
    return blocks


@pytest.mark.parametrize("index", [0, 1])
def test_readme_example_runs(index, tmp_path):
    code = python_blocks()[index]
    script = tmp_path / f"example_{index}.py"
    script.write_text(code)
    done = subprocess.run(
        [sys.executable, str(script)], cwd=REPO, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip(), "the example prints its answers"
