"""Output files that are whole or absent.

Every output file is written to a temporary name in its own folder and renamed into
place when complete (:func:`replacing`): a command that is killed, runs out of disk or
meets a permission error leaves either the previous file, the new file whole, or no
file -- never a truncated one. The temporary file of a failed write is removed; a
failure is one :class:`~geofix.errors.OutputError` naming the path (``disk full``,
``permission denied``, ...).

Temporary names are hidden (``.NAME.PID-RANDOM.part``); :func:`remove_parts` clears those
a killed process left behind.
"""

from __future__ import annotations

import contextlib
import errno
import os
import secrets
from collections.abc import Callable, Iterator
from pathlib import Path

from geofix.errors import GeofixError, OutputError

PART_SUFFIX = ".part"
_REASONS = {
    errno.ENOSPC: "disk full",
    errno.EDQUOT: "disk quota exceeded",
    errno.EACCES: "permission denied",
    errno.EPERM: "permission denied",
    errno.EROFS: "read-only file system",
    errno.EISDIR: "is a folder",
    errno.ENOTDIR: "a parent is not a folder",
    errno.ENOENT: "folder does not exist",
}


def output_error(path: str | Path, exc: BaseException) -> OutputError:
    """One plain :class:`OutputError` for a failed write of ``path``.

    Parameters
    ----------
    path : str or pathlib.Path
        The output file (its final name, not the temporary one).
    exc : BaseException
        What the writer raised: an OSError gives its reason (``disk full``,
        ``permission denied``, ...), anything else its first line.
    """
    code = getattr(exc, "errno", None)
    reason = _REASONS.get(code) if isinstance(code, int) else None
    if reason is None:
        reason = getattr(exc, "strerror", None) or _first_line(exc)
    return OutputError(f"cannot write {path}: {reason}")


def _first_line(exc: BaseException) -> str:
    lines = str(exc).strip().splitlines()
    return lines[0] if lines else type(exc).__name__


def check_target(path: str | Path) -> Path:
    """The output path, refused (OutputError) when it exists and is not a regular file.

    A folder, a device (``/dev/null``) or a pipe cannot be replaced by a finished file.
    """
    path = Path(path)
    if path.exists() and not path.is_file():
        what = "a folder" if path.is_dir() else "not a regular file"
        raise OutputError(f"cannot write {path}: it is {what}; give a file name")
    return path


def _part_name(path: Path) -> Path:
    """A fresh hidden temporary name beside ``path`` (same folder, so a rename is atomic)."""
    return path.with_name(f".{path.name}.{os.getpid()}-{secrets.token_hex(4)}{PART_SUFFIX}")


@contextlib.contextmanager
def replacing(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path to write; rename it to ``path`` when the block succeeds.

    Parameters
    ----------
    path : str or pathlib.Path
        The output file. Its folder is created if needed.

    Yields
    ------
    pathlib.Path
        Where to write the whole file (same folder as ``path``).

    Raises
    ------
    OutputError
        The folder cannot be created, the target is not a regular file, or the write
        or the rename failed with an OSError (disk full, permission denied, ...); the
        temporary file is removed and ``path`` is left as it was.
    """
    path = check_target(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise output_error(path, exc) from None
    part = _part_name(path)
    try:
        yield part
        _sync(part)
        os.replace(part, path)
    except OSError as exc:
        _remove(part)
        raise output_error(path, exc) from None
    except BaseException:
        _remove(part)
        raise


def write_atomic(path: str | Path, write: Callable[[Path], object]) -> Path:
    """Call ``write(temporary_path)`` and rename the result to ``path``; return ``path``.

    A :class:`GeofixError` from ``write`` passes through; any other error of the writer
    (a library's own error type for a full disk, say) becomes an :class:`OutputError`
    naming ``path``. See :func:`replacing`.
    """
    path = Path(path)
    with replacing(path) as part:
        try:
            write(part)
        except (GeofixError, OSError, MemoryError, KeyboardInterrupt):
            raise
        except Exception as exc:  # writers (netCDF, matplotlib) raise their own types
            raise output_error(path, exc) from None
    return path


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` whole or not at all (see :func:`replacing`)."""
    return write_atomic(path, lambda part: part.write_text(text, encoding="utf-8"))


def remove_parts(folder: str | Path, names: tuple[str, ...]) -> None:
    """Delete temporary files of ``names`` that a killed writer left in ``folder``."""
    folder = Path(folder)
    for name in names:
        for part in folder.glob(f".{name}.*{PART_SUFFIX}"):
            _remove(part)


def _sync(path: Path) -> None:
    """Flush a finished file to the disk before it is renamed into place."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _remove(path: Path) -> None:
    with contextlib.suppress(OSError):
        path.unlink()
