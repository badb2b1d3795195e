"""Quanser 2-DOF serial flexible link: a two-link arm, outside jaxflex's one-link model.

The files (motor currents, joint angles and strain-gauge deflection angles of both stages) can
be fetched for inspection, but no record is converted: the second link and its motor ride on the
first, flexible link, which a single-link model cannot describe.
"""

from __future__ import annotations

from pathlib import Path

from jaxflex.data import Record
from jaxflex.datasets._source import DatasetError, Source

_RESULTS = "software/quanser_original/Results"
_HASHES = {
    "data_fsf_Im1.mat": "2571c01177a84beb218fb9a3690f7df4c9ce0488a37cc6d0ec92b306e4fe9638",
    "data_fsf_Im2.mat": "0fed65953f6b0714c914a812c47e8f9a0fe1ff5f39df9103aaf01476f40c36b0",
    "data_fsf_th11.mat": "deb81153d67653884e208e6c33867118e709df8da1160e007a5ee755fbd6cd92",
    "data_fsf_th12.mat": "efcaeeb2d0816cf920c8be6ee582f3f3d3a793d118e81e98962ed9d54bf0a073",
    "data_fsf_th21.mat": "c1313c875b415090e0fb423a5864655c58398cbc96718399425f69d9918a02e7",
    "data_fsf_th22.mat": "3b59520e7aea5c54a76cb4a48276ef94075360f9b304687b73f7084659bdac36",
    "data_psf_Im1.mat": "61f170299d312e6f5eca18c72923a98efddc621ee0148f4e3edc2b774b234683",
    "data_psf_Im2.mat": "6b84cff671fa306cbc3d5a94a6daae7dca6e2e6c71c21cf272a764cf09d1556e",
    "data_psf_th11.mat": "3ccfdc340e17936ac0abf23ede82a0c1ad316def7ba8dd9f7bcd94fedca4b9fe",
    "data_psf_th12.mat": "7d4dd0187ca667edba575cc7b93acb803a9114b7c573e2944e299cdb864b676e",
    "data_psf_th21.mat": "af081c164c1bfeec15216678913f493007221476d5ca4ec80c83ca8f4fb8a580",
    "data_psf_th22.mat": "bc9c5f8be187211979cd917c097a5f0379a0322fc1a105d772e01084c9f9e104",
}

SOURCE = Source(
    name="quanser_2dsfl",
    repository="basta/quanser-2-dof-serial-flexible-link",
    commit="48ab0ce6a1b3038e971dec828005c72e90a12e5a",
    files={
        "LICENSE.quanser-2-dof-serial-flexible-link": (
            "LICENSE",
            "740abde8b24bed113d2272785c0f943a7066e500336ac764e9a9a590e1f2de13",
        ),
    }
    | {name: (f"{_RESULTS}/{name}", sha) for name, sha in _HASHES.items()},
    licence="LICENSE.quanser-2-dof-serial-flexible-link",
    licence_name="MIT, (c) 2022 aa4cc / Edu Ctrl Lab Models, CTU Prague",
    citation="Quanser 2-DOF serial flexible link, example results (Quanser, 2011)",
    description=(
        "Quanser 2-DOF serial flexible link: two flexible links in series, current-mode drives, "
        "encoders and strain gauges on both stages"
    ),
)
"""Origin of the files: repository at a pinned commit, files with SHA-256, licence."""

RECORDS: dict[str, str] = {}
"""The records of this data set by name: none, the arm has two links (see above)."""


def convert(files: dict[str, Path]) -> dict[str, Record]:
    """Refuses: this rig is a two-link arm (see the module doc)."""
    raise DatasetError(
        f"{SOURCE.name}: a two-link arm (the second motor and link ride on the first, flexible "
        "link); jaxflex models a single flexible link, so no record is converted. The raw files "
        f"are in {files[SOURCE.licence].parent}"
    )
