"""A study's JSON: everything but the times reproduces, so the times are kept under "timing"."""

from __future__ import annotations

import json

import numpy as np

from jaxflex.study import STUDY_FORMAT, Study, StudyRun


def study(wall_times: tuple[float, float]) -> Study:
    """Two DE runs, the same but for how long they took."""
    runs = tuple(
        StudyRun(method="de", seed=seed, params={"E": 7e10 + seed}, cost=0.1 * seed,
                 cost_search=0.2, wall_time=wall, compile_time=2.0 * wall,
                 history=np.array([1.0, 0.5]))
        for seed, wall in zip((0, 1), wall_times, strict=True)
    )
    return Study(runs=runs, names=("E",), record_names=("pulse",), settings={"seeds": [0, 1]})


def test_two_studies_that_differ_only_in_time_differ_only_under_timing(tmp_path):
    first, second = (json.loads(s.to_json(tmp_path / f"{i}.json").read_text())
                     for i, s in enumerate((study((1.0, 3.0)), study((5.0, 9.0)))))
    assert first["format"] == STUDY_FORMAT == "jaxflex-study/2"
    assert set(first["summary"]["de"]) == {"E", "cost", "cost_search", "seeds"}
    assert first["timing"] == {"de": {"wall_time": {"mean": 2.0, "std": 2 ** 0.5}}}
    assert second["timing"]["de"]["wall_time"]["mean"] == 7.0
    for data in (first, second):
        del data["timing"]
        for run in data["runs"]:
            del run["timing"]
    assert first == second


def test_the_table_still_shows_the_wall_time():
    assert "wall time s" in study((1.0, 3.0)).table().splitlines()[-1]
