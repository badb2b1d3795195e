"""The benchmark scripts' ``--out``: checked before any work, so a bad path costs no run."""

from __future__ import annotations

import argparse
from pathlib import Path

from jaxflex._io import OutputError, check_writable


def checked_out(parser: argparse.ArgumentParser, path: str, suffixes=(".json",)) -> Path:
    """``path`` once a file can be written there (replacing a result); else the parser's
    one-line error, exit status 2."""
    try:
        return check_writable(path, overwrite=True, suffixes=suffixes)
    except OutputError as error:
        parser.error(str(error))
