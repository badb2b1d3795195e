"""Progress bars: shown when asked for, silent when switched off, best cost as the postfix."""

from __future__ import annotations

import jax.numpy as jnp
import pytest

from jaxflex import _progress as progress
from jaxflex._progress import ENVIRONMENT_SWITCH, Progress
from jaxflex.evolve import DE, run


@pytest.fixture
def progress_on(monkeypatch):
    monkeypatch.delenv(ENVIRONMENT_SWITCH, raising=False)


def test_bar_shows_label_count_and_message(progress_on, capsys):
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
    assert items == ["a", "b", "c"]
    assert capsys.readouterr().err == ""


def test_disabled_bar_is_a_pass_through(progress_on, capsys):
    bar = Progress(range(3), label="search", enabled=False)
    assert list(bar) == [0, 1, 2]
    assert capsys.readouterr().err == ""


def test_bar_is_closed_when_the_loop_breaks(progress_on, capsys):
    bar = Progress(range(100), label="search")
    for i in bar:
        if i == 2:
            break
    err = capsys.readouterr().err
    assert "2/100" in err and err.endswith("\n")  # closed: the line is finished


def test_text_bar_when_the_widget_cannot_be_drawn(progress_on, monkeypatch, capsys):
    def no_widget(*args, **kwargs):
        raise ImportError("IProgress not found. Please update jupyter and ipywidgets.")

    monkeypatch.setattr(progress, "tqdm", no_widget)
    assert list(Progress(range(3), label="search")) == [0, 1, 2]
    assert "3/3" in capsys.readouterr().err


def test_evolution_shows_the_best_cost(progress_on, capsys):
    result = run(DE.paper(population=8), lambda x: jnp.sum(x**2, axis=1), 2, seed=0,
                 generations=3, progress=True)
    err = capsys.readouterr().err
    assert "3/3" in err
    assert f"best {float(result.history_best[-1]):.3e}" in err
