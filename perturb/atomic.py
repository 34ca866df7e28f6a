"""Output files that are either complete or absent.

Every file perturb writes for a user (CSV, PNG, LaTeX, JSON, netCDF) goes through
:func:`atomic_path` or :func:`write_text`: the content is written to a temporary file in the
destination's own folder and renamed over the destination only when it is complete, so a
killed process or a full disk never leaves a truncated file behind (a rename within one folder
is atomic on POSIX and Windows).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from perturb.errors import ParameterError

__all__ = ["atomic_path", "write_text", "write_bytes", "check_distinct"]


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` on success.

    The temporary file keeps ``path``'s suffix (or ``suffix``) so that writers that choose a
    format by extension (``matplotlib.savefig``, ``xarray.to_netcdf``) still do. On any
    exception the temporary file is removed and ``path`` is left as it was.

    Raises
    ------
    ParameterError
        If the destination folder does not exist or is not writable.
    """
    dest = Path(path)
    folder = dest.parent if str(dest.parent) else Path(".")
    if not folder.is_dir():
        raise ParameterError(f"output {str(dest)!r}: the folder {str(folder)!r} does not exist")
    if dest.is_dir():
        raise ParameterError(f"output {str(dest)!r} is a folder, expected a file name")
    try:
        fd, tmp_name = tempfile.mkstemp(
            prefix=f".{dest.name}.",
            suffix=suffix if suffix is not None else dest.suffix,
            dir=folder,
        )
    except OSError as exc:
        raise ParameterError(
            f"output {str(dest)!r}: cannot write in {str(folder)!r} ({exc.strerror})"
        ) from None
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        if dest.exists():
            with contextlib.suppress(OSError):
                os.chmod(tmp, dest.stat().st_mode & 0o7777)
        else:
            with contextlib.suppress(OSError):
                umask = os.umask(0)
                os.umask(umask)
                os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, dest)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` to ``path`` atomically (complete or absent)."""
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (complete or absent)."""
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())


def check_distinct(paths: Iterable[str | os.PathLike]) -> None:
    """Refuse two outputs of one run that resolve to the same file.

    Raises
    ------
    ParameterError
        Naming the path that two outputs share.
    """
    seen: set[str] = set()
    for p in paths:
        if p is None:
            continue
        key = os.path.realpath(os.fspath(p))
        if key in seen:
            raise ParameterError(
                f"two outputs are both written to {os.fspath(p)!r}: give them distinct names"
            )
        seen.add(key)
