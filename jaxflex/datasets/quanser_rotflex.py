"""Quanser SRV02 + rotary flexible link (ROTFLEX): two closed-loop runs in the horizontal plane.

Both runs log the motor voltage (a feedback command, measured), the SRV02 encoder (4096
counts/rev) and the root strain gauge, calibrated by Quanser as the link deflection angle α
(tip deflection ≈ L·α). Converted records:

* ``square_wave`` — a rate-limited ±30° square-wave set point, 500 Hz, 5 s (fit on this);
* ``random_985`` — a band-limited random reference, 1 kHz, 60 s (held out for validation).

Angles are converted to radians; the loop's reference is kept as the extra column ``reference``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jaxflex.data import Record
from jaxflex.datasets._source import DatasetError, Source

SOURCE = Source(
    name="quanser_rotflex",
    repository="frank1ma/DDRTC-of-UMSs",
    commit="2e08b3a202a0699c1cc4849d5b56c6de20054cc1",
    files={
        "LICENSE.DDRTC-of-UMSs": (
            "LICENSE",
            "8ed9a86874e54d48acdc1ead0d0c016b991b476019ebbd3ffd1a1e8df8c8431b",
        ),
        "data_theta.mat": (
            "SparseID/Data/data_theta.mat",
            "e45d369d68dbd1271ff44adb39a31f78757829c65dc0a03401deaa8e897c986a",
        ),
        "data_alpha.mat": (
            "SparseID/Data/data_alpha.mat",
            "43c1d7d835cdb09df640d0d8645628e64093ada71bf65fda897aa2eb47e3b347",
        ),
        "data_vm.mat": (
            "SparseID/Data/data_vm.mat",
            "b0657ef64eefa83955009884994049786cc8294b6b5fb6b3628d45928ecd21b9",
        ),
        "theta985.mat": (
            "relatek_opt/theta985.mat",
            "2e3be38275a86a072c49d37097547200b9aa52562f490fec0f811ef17a9a1232",
        ),
        "alpha985.mat": (
            "relatek_opt/alpha985.mat",
            "8e38570fe99f6cfe88951403a3677cb4767c5daa388cf9e955723e309c64b607",
        ),
        "voltage985.mat": (
            "relatek_opt/voltage985.mat",
            "422fbd6e89370f82089f9d7edf0cd169f41181fa0bb1ff7a7a7ebdf565ada070",
        ),
    },
    licence="LICENSE.DDRTC-of-UMSs",
    licence_name="MIT, (c) 2021 SJM-Frank",
    citation=(
        "S. F. Ma and J.-Q. Sun, Data-driven robust tracking control of underactuated mechanical "
        "systems using identified flat output, Int. J. Control, 2021"
    ),
    description=(
        "Quanser SRV02 + rotary flexible link (ROTFLEX), horizontal plane; motor voltage, "
        "encoder and root strain gauge (calibrated as a link deflection angle)"
    ),
)
"""Origin of the records: repository at a pinned commit, files with SHA-256, licence."""

RECORDS: dict[str, str] = {
    "square_wave": "closed loop, ±30° rate-limited square-wave set point; 500 Hz, 5 s (fit)",
    "random_985": "closed loop, band-limited random reference; 1 kHz, 60 s (held out)",
}
"""The records of this data set by name, with what each holds."""

CHANNELS = (
    "voltage V: motor voltage command (measured); joint_angle rad: SRV02 encoder, 4096 "
    "counts/rev; deflection_angle rad: root strain gauge calibrated as the link deflection "
    "angle; reference rad: the position loop's reference"
)
"""The channels of its records, with units and sensors."""


def _matrix(path: Path, variable: str, rows: int) -> np.ndarray:
    """The ``variable`` of a .mat file as a ``(rows, n)`` float64 array (signals along axis 1)."""
    from scipy.io import loadmat

    data = loadmat(path)
    if variable not in data:
        raise DatasetError(f"{path}: no variable {variable!r}")
    matrix = np.asarray(data[variable], dtype=np.float64)
    matrix = matrix if matrix.shape[0] == rows else matrix.T
    if matrix.ndim != 2 or matrix.shape[0] != rows:
        raise DatasetError(
            f"{path}: {variable!r} has shape {data[variable].shape}, expected {rows} signals"
        )
    return matrix


def _same_time(time: np.ndarray, other: np.ndarray, path: Path) -> None:
    if not np.array_equal(time, other):
        raise DatasetError(f"{path}: its time column differs from the other files of the run")


def _run(files: dict[str, Path], *names: tuple[str, str, int]) -> list[np.ndarray]:
    """The matrices of one run, given as (file, variable, rows) for the angle, the deflection
    and the voltage; every file must share the angle file's time column."""
    theta, *others = (_matrix(files[name], variable, rows) for name, variable, rows in names)
    for (name, _, _), other in zip(names[1:], others, strict=True):
        _same_time(theta[0], other[0], files[name])
    return [theta, *others]


def convert(files: dict[str, Path]) -> dict[str, Record]:
    """The two runs as records (see the module doc), in SI units."""
    theta, alpha, volts = _run(
        files, ("data_theta.mat", "data_theta", 3), ("data_alpha.mat", "data_alpha", 2),
        ("data_vm.mat", "data_vm", 2),
    )
    square = dict(
        time=theta[0],
        joint_angle=np.deg2rad(theta[2]),
        extras={
            "voltage": volts[1],
            "deflection_angle": np.deg2rad(alpha[1]),
            "reference": np.deg2rad(theta[1]),
        },
        files="data_theta.mat, data_alpha.mat, data_vm.mat",
    )
    theta, alpha, volts = _run(
        files, ("theta985.mat", "theta", 3), ("alpha985.mat", "alpha", 2),
        ("voltage985.mat", "u", 2),
    )
    random = dict(
        time=theta[0],
        joint_angle=theta[2],
        extras={"voltage": volts[1], "deflection_angle": alpha[1], "reference": theta[1]},
        files="theta985.mat, alpha985.mat, voltage985.mat",
    )
    return {
        name: Record(
            time=columns["time"],
            joint_angle=columns["joint_angle"],
            extras=columns["extras"],
            name=name,
            metadata={
                "dataset": f"{SOURCE.name}/{name}",
                "description": RECORDS[name],
                "rig": SOURCE.description,
                "channels": CHANNELS,
                "source": f"{SOURCE.source_line}: {columns['files']}",
                "licence": f"{SOURCE.licence_name}; see {SOURCE.licence}",
                "cite": SOURCE.citation,
            },
        )
        for name, columns in (("square_wave", square), ("random_985", random))
    }
