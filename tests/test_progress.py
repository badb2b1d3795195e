"""Progress: a bar on a terminal, a line per stage elsewhere, silent when not asked for or
switched off; the best cost as the bar's postfix."""

from __future__ import annotations

import io
import sys

import jax.numpy as jnp
import pytest

from jaxflex import _progress as progress
from jaxflex._progress import ENVIRONMENT_SWITCH, Progress, progress_mode, stage
from jaxflex.evolve import DE, run


class Terminal(io.StringIO):
    """A stderr that says it is a terminal."""

    def isatty(self) -> bool:
        return True


@pytest.fixture
def progress_on(monkeypatch):
    """Progress as the output stream decides (captured: not a terminal)."""
    monkeypatch.delenv(ENVIRONMENT_SWITCH, raising=False)


@pytest.fixture
def bars_on(monkeypatch):
    monkeypatch.setenv(ENVIRONMENT_SWITCH, "1")


def test_the_stream_decides_and_the_switch_overrides(monkeypatch):
    monkeypatch.delenv(ENVIRONMENT_SWITCH, raising=False)
    assert progress_mode(True, Terminal()) == "bar"
    assert progress_mode(True, io.StringIO()) == "lines"
    assert progress_mode(False, Terminal()) == "off"
    monkeypatch.setenv(ENVIRONMENT_SWITCH, "1")
    assert progress_mode(True, io.StringIO()) == "bar"
    assert progress_mode(False, io.StringIO()) == "off"  # not asked for: the switch adds none
    monkeypatch.setenv(ENVIRONMENT_SWITCH, "0")
    assert progress_mode(True, Terminal()) == "off"


def test_a_terminal_gets_a_bar(progress_on, monkeypatch):
    terminal = Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    assert list(Progress(range(3), label="search")) == [0, 1, 2]
    assert "\r" in terminal.getvalue() and "search: 100%" in terminal.getvalue()


def test_elsewhere_a_line_per_stage_and_no_bar(progress_on, capsys):
    bar = Progress(range(4), label="search")
    for i in bar:
        bar.set_message(f"best {10.0**-i:.1e}")
    stage("refinement: successful")
    runs = Progress(["de", "ga", "pso"], label="study", each_stage=True)
    for method in runs:
        runs.set_message(f"{method}: cost 1")
        if method == "ga":
            break
    err = capsys.readouterr().err
    assert "\r" not in err
    assert err.splitlines() == [
        "search: 4/4 in 0.0 s, best 1.0e-03",
        "refinement: successful",
        "study 1/3: de: cost 1",
        "study 2/3: ga: cost 1",
        "study: 2/3 in 0.0 s",
    ]


def test_bar_shows_label_count_and_message(bars_on, capsys):
    bar = Progress(range(4), label="search")
    seen = []
    for i in bar:
        seen.append(i)
        bar.set_message(f"best {10.0**-i:.1e}")
    err = capsys.readouterr().err
    assert seen == [0, 1, 2, 3]
    assert "search" in err and "4/4" in err and "best 1.0e-03" in err


@pytest.mark.parametrize("value", ["0", "false", "OFF", " no "])
def test_environment_switch_silences_every_bar(monkeypatch, capsys, value):
    monkeypatch.setenv(ENVIRONMENT_SWITCH, value)
    bar = Progress(iter("abc"), label="search")
    assert not bar.enabled
    items = []
    for item in bar:
        items.append(item)
        bar.set_message("best 1")
    stage("refinement: successful")
    assert items == ["a", "b", "c"]
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("switch", [None, "1"])
def test_disabled_bar_is_a_pass_through(monkeypatch, capsys, switch):
    if switch is None:
        monkeypatch.delenv(ENVIRONMENT_SWITCH, raising=False)
    else:
        monkeypatch.setenv(ENVIRONMENT_SWITCH, switch)
    bar = Progress(range(3), label="search", enabled=False)
    assert list(bar) == [0, 1, 2]
    stage("refinement: successful", enabled=False)
    assert capsys.readouterr().err == ""


def test_bar_is_closed_when_the_loop_breaks(bars_on, capsys):
    bar = Progress(range(100), label="search")
    for i in bar:
        if i == 2:
            break
    err = capsys.readouterr().err
    assert "2/100" in err and err.endswith("\n")  # closed: the line is finished


def test_text_bar_when_the_widget_cannot_be_drawn(bars_on, monkeypatch, capsys):
    def no_widget(*args, **kwargs):
        raise ImportError("IProgress not found. Please update jupyter and ipywidgets.")

    monkeypatch.setattr(progress, "tqdm", no_widget)
    assert list(Progress(range(3), label="search")) == [0, 1, 2]
    assert "3/3" in capsys.readouterr().err


def test_a_stage_that_stops_the_loop_is_counted(bars_on, capsys):
    """A discovery that stops at its second step shows 2 steps done, not 1."""
    steps = Progress(range(5), label="discover", each_stage=True)
    for i in steps:
        steps.set_message("none confirmed" if i else "confirmed payload")
        if i == 1:
            break
    assert "2/5" in capsys.readouterr().err


@pytest.mark.parametrize("fixture", ["bars_on", "progress_on"])
def test_evolution_shows_the_best_cost(request, capsys, fixture):
    request.getfixturevalue(fixture)
    result = run(DE.paper(population=8), lambda x: jnp.sum(x**2, axis=1), 2, seed=0,
                 generations=3, progress=True)
    err = capsys.readouterr().err
    assert "3/3" in err
    assert f"best {float(result.history_best[-1]):.3e}" in err
