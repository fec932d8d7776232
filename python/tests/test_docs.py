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


def _wire_vector(text, n):
    """The bytes of valid vector ``n`` of docs/wire.md §8."""
    start = text.index(f"**Vector {n}:")
    block = re.search(r"```hex\n(.*?)```", text[start:], re.S)
    return bytes.fromhex(block.group(1))


def test_the_wire_specs_reference_encoder_writes_its_vectors():
    # The spec's Python encoder is the one a reader of the spec copies:
    # it must write the spec's own vectors, byte for byte.
    text = (ROOT / "docs" / "wire.md").read_text(encoding="utf-8")
    section = text[text.index("## 7. Reference encoder") :]
    ns = {}
    exec(BLOCK.search(section).group(1), ns)
    none = ns["NONE"]
    close = ns["close"](4, seq=1, sent_at=2_000_000, echo=5_000_000, hold=500_000)
    assert close == _wire_vector(text, 7)
    bundle = ns["bundle"](
        0x5555666677778888,
        [1.5, -0.25],
        [(41, 1_480_000_000, 39, [1.25, -0.5]), (40, 1_460_000_000, none, [1.0, -0.75])],
        repeat=1,
        missed=7,
        seq=42,
        sent_at=1_500_000_000,
        echo=1_300_000_000,
        hold=2_500_000,
        released=40,
    )
    assert bundle == _wire_vector(text, 8)
    token = ns["token"](
        0x0123456789ABCDEF,
        seq=1300,
        sent_at=260_000_000_000,
        echo=259_990_000_000,
        hold=2_000_000,
        released=1290,
    )
    assert token == _wire_vector(text, 9)
