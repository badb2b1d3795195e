"""The README's ten-line API example runs and tells the story it promises."""

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


@pytest.mark.slow  # a full DE identification and a discovery run: about 2 minutes
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
