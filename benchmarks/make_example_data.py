"""Make the bundled example data set ``jaxflex/data/example_*.csv``: an arm with a hidden payload.

The "real" arm differs from the paper's reference values in every base parameter and carries a
30 g tip payload that the base model does not know about. Records: the three reference inputs
to fit on and a weaker pulse held out for validation, with the spec's sensor noise (encoder
4096 counts/rev, accelerometer sigma 0.05 m/s^2) from a fixed seed. The metadata of each file
give the answer, for whoever wants to check it.

Run ``python benchmarks/make_example_data.py [--check]``; ``--check`` verifies that the bundled
files are what this script makes, to the simulator's accuracy (the tests run it).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from jaxflex.data import load_record, save_record
from jaxflex.effects import Payload
from jaxflex.model import Model
from jaxflex.synthetic import make_records

#: The arm's base parameters (each away from the reference values) and the hidden payload.
TRUE_PARAMETERS = {
    "E": 5.2e10,
    "J_h": 0.0062,
    "b_v": 1.2e-3,
    "tau_c": 0.09,
    "alpha": 1.3,
    "beta": 9e-5,
    "m_p": 0.03,
}
SEED = 2024
FIT_INPUTS = ("triangular", "pulse", "half_sine")
HOLDOUT = {"pulse": 0.18}
DATA = Path(__file__).resolve().parents[1] / "jaxflex" / "data"


def example_records():
    """(fit records, held-out records) of the example arm."""
    model = Model().with_effects(Payload())
    fit = make_records(model, TRUE_PARAMETERS, inputs=FIT_INPUTS, seed=SEED)
    held = make_records(model, TRUE_PARAMETERS, inputs=tuple(HOLDOUT), amplitudes=HOLDOUT,
                        seed=SEED + 1)
    note = {"answer": "a hidden tip payload m_p = 0.03 kg",
            "made_by": "benchmarks/make_example_data.py"}

    def labelled(record, name):
        kept = {k: v for k, v in record.metadata.items() if k not in ("parameters", "effects")}
        return record.replace(name=name, metadata=kept | note)

    return ([labelled(r, f"example_{r.name}") for r in fit],
            [labelled(r, f"example_holdout_{r.name}") for r in held])


def write(directory: Path, overwrite: bool = False) -> list[Path]:
    fit, held = example_records()
    paths = [save_record(r, directory / f"{r.name}.csv", overwrite=overwrite) for r in fit + held]
    for path in paths:
        path.chmod(0o644)  # package data: readable by everyone
    return paths


def same(a, b) -> bool:
    """The records agree to the simulator's numerical accuracy: an acceleration within 1e-5 m/s²
    (the sensor noise is 0.05), an angle within one encoder count at no more than two samples.
    Another BLAS, XLA version or eigen-solver moves the last digits."""
    import numpy as np

    if a.metadata != b.metadata or a.columns != b.columns:
        return False
    if not (np.array_equal(a.time, b.time) and np.array_equal(a.torque, b.torque)):
        return False
    counts = np.round(np.abs(a.joint_angle - b.joint_angle) / (2 * np.pi / 4096))
    return bool(np.sum(counts > 0) <= 2 and np.all(counts <= 1)
                and np.allclose(a.tip_acceleration, b.tip_acceleration, rtol=0, atol=1e-5))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true",
                        help="compare the bundled files with freshly made ones")
    parser.add_argument("--out", type=Path, default=DATA, help="directory (default: %(default)s)")
    args = parser.parse_args(argv)
    if not args.check:
        for path in write(args.out, overwrite=True):
            print(f"wrote {path}")
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        fresh = write(Path(tmp))
        bad = [p.name for p in fresh
               if not (args.out / p.name).is_file() or not same(load_record(p),
                                                                load_record(args.out / p.name))]
    if bad:
        print(f"bundled example files differ from the script's output: {bad}", file=sys.stderr)
        return 1
    print(f"{len(fresh)} example files match")
    return 0


if __name__ == "__main__":
    sys.exit(main())
