"""The bundled example records of an arm with a hidden effect."""

from __future__ import annotations

from pathlib import Path

from jaxflex.data import Dataset


def load_example() -> tuple[Dataset, Dataset]:
    """The bundled example: (three records to fit, one held out) of an arm with a hidden effect.

    Made by ``benchmarks/make_example_data.py`` (base parameters away from the reference values,
    the spec's sensor noise, a fixed seed); the files' comments give the answer.
    """
    from importlib import resources

    from jaxflex.data import load_record

    folder = resources.files("jaxflex") / "data"
    files = sorted(p for p in folder.iterdir() if p.name.startswith("example_"))
    if not files:
        raise FileNotFoundError(f"no example records in {folder}; run "
                                "benchmarks/make_example_data.py")
    records = [load_record(Path(str(p))) for p in files]
    fit = Dataset(r for r in records if "holdout" not in r.name)
    return fit, Dataset(r for r in records if "holdout" in r.name)


__all__ = [
    "load_example",
]
