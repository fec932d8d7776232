"""Every Python block of the README and the user guide runs as printed
(each in a fresh namespace), so that the examples a newcomer copies
cannot rot. A block whose first line is ``# on two hosts`` needs machines
this test does not have: it is compiled, not run."""

import pathlib
import re

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs" / "guide").glob("*.md"))]
BLOCK = re.compile(r"^```python\n(.*?)^```", re.S | re.M)


def _blocks():
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        for n, match in enumerate(BLOCK.finditer(text), start=1):
            line = text.count("\n", 0, match.start()) + 2
            name = f"{page.relative_to(ROOT)}:{line}"
            yield pytest.param(name, match.group(1), id=f"{page.relative_to(ROOT)}#{n}")


BLOCKS = list(_blocks())


def test_the_readme_and_the_guide_have_python_examples():
    assert len(PAGES) > 5, PAGES
    assert len(BLOCKS) >= 8, [b.id for b in BLOCKS]


@pytest.mark.parametrize("name, code", BLOCKS)
def test_a_documented_python_block_runs(name, code, capsys):
    compiled = compile(code, name, "exec")
    if code.startswith("# on two hosts"):
        return
    exec(compiled, {"__name__": "__docs__"})
    capsys.readouterr()
