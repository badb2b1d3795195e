"""DaISy 96-009, a flexible robot arm: reaction torque in, arm acceleration out.

1024 samples of a periodic sine sweep in periodic steady state (not from rest). The sampling
period, the units, the geometry and the accelerometer's position are not published: the
record's time is the sample index times :data:`ASSUMED_DT`, the period the packaged rig
``daisy_robot_arm`` assumes (so that the record and the rig agree), and both channels are in
raw units: a model of it needs the time scale and a sensor gain identified, and it holds no
joint angle.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jaxflex.data import Record
from jaxflex.datasets._source import DatasetError, Source

SOURCE = Source(
    name="daisy_robot_arm",
    repository="SLICOT/SLICOT-SystemIdentification",
    commit="947f1c5edd3f9455577c3ac3505bdc0caa13e042",
    files={
        "LICENSE.SLICOT-SystemIdentification": (
            "LICENSE",
            "d5f796f1075cb6ffa4d9dd839a4297933ab37875913a82b37ce84d618b4058a2",
        ),
        "robot_arm_dat.mat": (
            "robot_arm_dat.mat",
            "0507e1ddf4471730e758ec6cc596aa15a5bd292e8f7d8f0dfa048dd43f0adc27",
        ),
    },
    licence="LICENSE.SLICOT-SystemIdentification",
    licence_name="BSD-3-Clause, (c) 2021 SLICOT",
    citation=(
        "DaISy 96-009, W. Favoreel (KU Leuven); data from H. Van Brussel and J. Swevers"
    ),
    description=(
        "DaISy flexible robot arm: reaction torque -> arm acceleration, periodic sine sweep; "
        "sampling period, units and geometry unpublished"
    ),
)
"""Origin of the record: repository at a pinned commit, files with SHA-256, licence."""

ASSUMED_DT = 0.01
"""Seconds between samples, assumed (unpublished): the packaged rig's ``sampling.dt``, chosen
so that the record's first resonance lands near its strip's first free-hub mode."""

RECORDS: dict[str, str] = {
    "sweep": f"periodic sine sweep, 1024 samples; {ASSUMED_DT:g} s apart, assumed (period "
             "unpublished)",
}
"""The records of this data set by name, with what each holds."""


def convert(files: dict[str, Path]) -> dict[str, Record]:
    """The sweep as a record with a ``torque`` input and an ``acceleration`` output (raw units)."""
    from scipy.io import loadmat

    path = files["robot_arm_dat.mat"]
    data = np.asarray(loadmat(path).get("robot_arm_dat", np.zeros((0, 0))), dtype=np.float64)
    if data.ndim != 2 or data.shape[1] != 2:
        raise DatasetError(f"{path}: 'robot_arm_dat' must be an n x 2 array, got {data.shape}")
    record = Record(
        time=ASSUMED_DT * np.arange(data.shape[0], dtype=np.float64),
        torque=data[:, 0],
        extras={"acceleration": data[:, 1]},
        name="sweep",
        metadata={
            "dataset": f"{SOURCE.name}/sweep",
            "description": RECORDS["sweep"],
            "rig": SOURCE.description,
            "channels": (
                f"time: sample index x {ASSUMED_DT:g} s (the sampling period is unpublished; "
                "the packaged rig daisy_robot_arm assumes it); torque: measured reaction "
                "torque, raw units; acceleration: arm acceleration, raw units, position unknown"
            ),
            "source": f"{SOURCE.source_line}: robot_arm_dat.mat",
            "licence": f"{SOURCE.licence_name}; see {SOURCE.licence}",
            "cite": SOURCE.citation,
        },
    )
    return {"sweep": record}
