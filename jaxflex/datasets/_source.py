"""A public data set's upstream files and how to get them: a local copy, the cache, the network.

Every file is the upstream original, byte for byte, pinned by commit and SHA-256; the project
commits none of them. :func:`fetch_files` looks in this order:

1. a local folder laid out like ``DIR/<data set>/<file>`` (``data_dir=`` or the
   ``JAXFLEX_DATA_DIR`` environment variable), each file checked against its hash;
2. otherwise pooch's user cache (``JAXFLEX_CACHE_DIR`` or the platform's cache folder), filled
   from the pinned upstream URL on first use and checked against the same hash.

The upstream URLs are those of raw.githubusercontent.com; ``JAXFLEX_DATA_URL`` names a mirror
laid out the same way (``<mirror>/<repository>/<commit>/<path>``). A download that fails leaves
nothing in the cache (no file, no empty folder) and is reported as one :class:`DataUnavailable`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import quote

DATA_DIR_VARIABLE = "JAXFLEX_DATA_DIR"
CACHE_DIR_VARIABLE = "JAXFLEX_CACHE_DIR"
URL_VARIABLE = "JAXFLEX_DATA_URL"
RAW_URL = "https://raw.githubusercontent.com"
"""Where GitHub serves a file of a repository at a commit (``$JAXFLEX_DATA_URL`` replaces it)."""


class DatasetError(ValueError):
    """A data set cannot be provided: unknown name, missing or corrupt file, no network."""


class DataUnavailable(DatasetError):
    """Neither a local copy nor the network can provide the files."""


@dataclass(frozen=True)
class Source:
    """One public repository at a pinned commit, and the files jaxflex uses from it.

    ``files`` maps the local file name to ``(upstream path, sha256)``; ``licence`` names the
    local file holding the licence, ``citation`` the work to cite wherever the data appear.
    """

    name: str
    repository: str
    commit: str
    files: dict[str, tuple[str, str]]
    licence: str
    licence_name: str
    citation: str
    description: str

    def url(self, file: str) -> str:
        """The raw-file URL of ``file`` at the pinned commit (spaces etc. URL-encoded), on
        ``$JAXFLEX_DATA_URL`` if set."""
        path = quote(self.files[file][0])
        base = (os.environ.get(URL_VARIABLE) or RAW_URL).rstrip("/")
        return f"{base}/{self.repository}/{self.commit}/{path}"

    def sha256(self, file: str) -> str:
        """The SHA-256 of ``file`` (hex)."""
        return self.files[file][1]

    @property
    def source_line(self) -> str:
        """Repository, commit and licence on one line, for a record's metadata."""
        return f"github.com/{self.repository} @ {self.commit[:7]} ({self.licence_name})"


def check_data_dir(data_dir: object, function: str) -> None:
    """A TypeError naming ``function`` and ``data_dir`` unless it is a folder's path or None."""
    if data_dir is not None and not isinstance(data_dir, (str, os.PathLike)):
        raise TypeError(f"{function}: data_dir must be a folder's path or None, got "
                        f"{data_dir!r} ({type(data_dir).__name__})")


def local_data_dir(data_dir: str | os.PathLike | None = None) -> Path | None:
    """The local copy to use: ``data_dir``, else ``$JAXFLEX_DATA_DIR``, else None."""
    check_data_dir(data_dir, "local_data_dir")
    chosen = data_dir if data_dir is not None else os.environ.get(DATA_DIR_VARIABLE) or None
    if chosen is None:
        return None
    path = Path(chosen)
    if not path.is_dir():
        origin = "data_dir" if data_dir is not None else DATA_DIR_VARIABLE
        raise DatasetError(f"{origin}={os.fspath(chosen)!r} is not a directory")
    return path


def cache_dir() -> Path:
    """Where downloaded files are kept: ``$JAXFLEX_CACHE_DIR`` or the user cache of jaxflex."""
    import pooch

    return Path(os.environ.get(CACHE_DIR_VARIABLE) or pooch.os_cache("jaxflex"))


def fetch_files(source: Source, data_dir: str | os.PathLike | None = None) -> dict[str, Path]:
    """Paths of every file of ``source``, each verified against its SHA-256 (see module doc)."""
    local = local_data_dir(data_dir)
    if local is not None:
        return {f: _verified(local / source.name / f, source.sha256(f)) for f in source.files}
    return {f: _download(source, f) for f in source.files}


def _verified(path: Path, sha256: str) -> Path:
    """``path`` if it exists and has the expected hash, else a DatasetError naming it."""
    import pooch

    if not path.is_file():
        raise DatasetError(
            f"{path}: file not found; a local data folder must hold "
            f"<folder>/{path.parent.name}/{path.name} as published upstream"
        )
    actual = pooch.file_hash(str(path), alg="sha256")
    if actual != sha256:
        raise DatasetError(
            f"{path}: SHA-256 is {actual}, expected {sha256}; the file differs from the "
            "published original (re-download it or remove it)"
        )
    return path


def _download(source: Source, file: str) -> Path:
    """The cached copy of ``file``, downloaded from its pinned URL on first use; a failed
    download leaves no folder it made behind, and pooch says nothing (the error says it all)."""
    import logging

    import pooch

    folder = cache_dir() / source.name
    made = [d for d in (folder, *folder.parents) if not d.exists()]
    logger = pooch.get_logger()
    level = logger.level
    logger.setLevel(logging.WARNING)  # not "Downloading data from ..." before the one line
    try:
        return Path(
            pooch.retrieve(
                source.url(file),
                known_hash=f"sha256:{source.sha256(file)}",
                fname=file,
                path=folder,
                progressbar=False,
            )
        )
    except ValueError as err:  # pooch's hash mismatch
        _remove_empty(made)
        raise DatasetError(f"{source.url(file)}: {err}") from None
    except OSError as err:  # no network, HTTP errors (requests' errors are OSErrors)
        _remove_empty(made)
        raise DataUnavailable(
            f"{source.name}: cannot download {source.url(file)} ({type(err).__name__}); "
            f"set {DATA_DIR_VARIABLE} (or pass data_dir) to a local copy laid out as "
            f"<folder>/{source.name}/{file}"
        ) from None
    finally:
        logger.setLevel(level)


def _remove_empty(folders: list[Path]) -> None:
    """Remove the folders (innermost first) that are still empty."""
    for folder in folders:
        try:
            folder.rmdir()
        except OSError:  # not empty, or gone: leave it
            return
