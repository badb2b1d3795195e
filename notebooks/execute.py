"""Execute notebooks in place, top to bottom, so that they are committed with their outputs.

Usage: ``python notebooks/execute.py notebooks/*.ipynb`` (``make notebooks`` runs it with the
test suite's environment). Each notebook runs in a fresh kernel in a scratch directory; a
notebook that raises is left untouched and the script exits with status 1.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import nbformat
from nbclient import NotebookClient
from nbclient.exceptions import CellExecutionError


def execute(path: Path, timeout: int = 3600) -> None:
    """Run ``path`` and replace it atomically with the executed notebook."""
    nb = nbformat.read(path, as_version=4)
    with tempfile.TemporaryDirectory() as scratch:
        client = NotebookClient(
            nb,
            kernel_name="python3",
            timeout=timeout,
            record_timing=False,
            resources={"metadata": {"path": scratch}},
        )
        client.execute()
    tmp = path.with_name(f".{path.name}.tmp")
    nbformat.write(nb, tmp)
    os.replace(tmp, path)


def main(paths: list[str]) -> int:
    failed = 0
    for name in paths:
        start = time.perf_counter()
        try:
            execute(Path(name))
        except CellExecutionError as error:
            failed += 1
            print(f"{name}: failed\n{error}", file=sys.stderr)
            continue
        print(f"{name}: executed in {time.perf_counter() - start:.0f} s")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
