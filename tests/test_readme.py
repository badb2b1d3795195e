"""The README is a short guide: its ten-line API example runs and tells the story it promises,
and every measured figure it quotes is generated from a results file."""

import re
from pathlib import Path

import pytest
from helpers import docs_module

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"


def test_readme_is_a_guide_of_at_most_200_lines():
    assert len(README.read_text(encoding="utf-8").splitlines()) <= 200


def test_readme_figures_are_generated_from_the_results_files():
    """The generated blocks are what ``docs/generated.py`` makes of the results files now, and
    no measured figure (a decimal number of per cent, times, seconds or hertz) stands outside
    them or a code block."""
    generated = docs_module("generated")
    text = README.read_text(encoding="utf-8")
    assert generated.BLOCK.search(text), "README has no generated block"
    assert generated.regenerate(text) == text, "stale: run python docs/generated.py"
    prose = re.sub(r"```.*?```", "", generated.BLOCK.sub("", text), flags=re.S)
    assert re.findall(r"\d+\.\d+ ?(?:%|×|s\b|ms\b|Hz\b)", prose) == []


def test_a_stale_generated_block_is_found():
    generated = docs_module("generated")
    stale = "<!-- generated: real_rig -->\n| 1 % |\n<!-- end generated -->\n"
    assert generated.regenerate(stale) != stale
    assert "| jaxflex, arm `quanser_rotflex` | 6 physical |" in generated.regenerate(stale)


@pytest.mark.slow  # a full DE identification and a discovery run
def test_api_example_runs_and_finds_the_hidden_payload(capsys):
    block = re.search(r"## Ten lines of API\n\n```python\n(.*?)```", README.read_text(), re.S)
    assert block, "README has no 'Ten lines of API' python block"
    code = block.group(1)
    assert len(code.strip().splitlines()) <= 11  # the import and ten lines
    exec(compile(code, str(README), "exec"), {})
    printed = capsys.readouterr().out
    assert "refinement: successful" in printed
    assert "held-out" in printed
    assert "base + payload" in printed
    assert "residuals are consistent with the measurement noise" in printed
