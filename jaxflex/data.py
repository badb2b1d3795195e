"""Measured records and their files, in one import: the containers (:mod:`jaxflex.records`),
the CSV and NPZ files (:mod:`jaxflex.record_files`) and the unit checks of what is read
(:mod:`jaxflex.units`).
"""

from jaxflex.record_files import MIN_FILE_SAMPLES as MIN_FILE_SAMPLES
from jaxflex.record_files import load_dataset, load_record, save_npz, save_record
from jaxflex.records import DATASET_DT_RTOL as DATASET_DT_RTOL
from jaxflex.records import (
    INPUT_COLUMNS,
    Dataset,
    Record,
    RecordError,
    RecordWarning,
)
from jaxflex.records import KNOWN_UNITS as KNOWN_UNITS
from jaxflex.records import OUTPUT_COLUMNS as OUTPUT_COLUMNS
from jaxflex.records import REQUIRED_COLUMNS as REQUIRED_COLUMNS
from jaxflex.records import UNIFORM_RTOL as UNIFORM_RTOL
from jaxflex.records import RowLabel as RowLabel
from jaxflex.records import resample_columns as resample_columns
from jaxflex.units import MAX_PLAUSIBLE_DT as MAX_PLAUSIBLE_DT
from jaxflex.units import MAX_PLAUSIBLE_INERTIA as MAX_PLAUSIBLE_INERTIA
from jaxflex.units import MIN_PLAUSIBLE_LENGTH as MIN_PLAUSIBLE_LENGTH
from jaxflex.units import check_units

__all__ = [
    "INPUT_COLUMNS",
    "Dataset",
    "Record",
    "RecordError",
    "RecordWarning",
    "check_units",
    "load_dataset",
    "load_record",
    "save_npz",
    "save_record",
]
