"""Opening and writing files safely: one place for every reader and writer of jaxnav.

* :func:`require_regular` and :func:`open_regular` refuse a path that is not a regular file (a
  folder, a named pipe, a device such as ``/dev/zero``, a socket) *before* it is opened: opening a
  named pipe for reading blocks until something writes into it, and a device reads as endless or
  empty data. The refusal, :class:`NotARegularFileError` (a ``ValueError``), names the path, what
  it is and what to do. A symbolic link is followed: a link to a regular file is a regular file.
* :func:`write_atomic` and :func:`write_atomic_path` write a file through a temporary file in the
  same folder, flushed to the disk and then renamed over the target (``os.replace``): a full disk,
  an exceeded quota or an interruption leave the previous file whole (or no file), never a
  truncated one. A failed write raises :class:`FileWriteError` (an ``OSError`` with the original
  ``errno``) whose message names the path, the cause in words (disk full, quota exceeded,
  read-only file system, permission denied) and what to do. A target that exists and is not a
  regular file is refused before anything is written (a rename would otherwise replace a named
  pipe or a device node by a plain file); a symbolic link is written through (its target is
  replaced, the link is kept).
"""

from __future__ import annotations

import errno
import os
import secrets
import stat
from collections.abc import Callable
from typing import IO, Any

__all__ = [
    "NotARegularFileError",
    "FileWriteError",
    "describe",
    "require_regular",
    "open_regular",
    "write_atomic",
    "write_atomic_path",
]


class NotARegularFileError(ValueError):
    """A path that must be a regular file is a folder, a named pipe (FIFO), a device or a socket.

    Attributes:
        path: the path, as given.
        kind: what it is, in words (``"a named pipe (FIFO)"``, ``"a folder"``, …).
    """

    def __init__(self, path: str | os.PathLike, kind: str, advice: str) -> None:
        self.path, self.kind = os.fspath(path), kind
        super().__init__(f"{self.path}: is {kind}, not a regular file; {advice}")


class FileWriteError(OSError):
    """A file that could not be written (disk full, quota exceeded, read-only, permission denied, …).

    ``errno`` is the original error's; ``filename`` the path; the message (``str``) names the path, the
    cause in words and what to do, on one line, ending with the caller's ``note``.
    """

    def __init__(self, path: str | os.PathLike, err: OSError, note: str = "") -> None:
        super().__init__(err.errno, err.strerror or str(err), os.fspath(path))
        cause, fix = _CAUSES.get(err.errno, (err.strerror or str(err) or type(err).__name__, "check the path"))
        self.message = (
            f"{os.fspath(path)}: cannot be written ({cause}); {fix}; nothing was written there "
            f"(a file already there is left as it was){'; ' + note if note else ''}"
        )

    def __str__(self) -> str:
        return self.message


_CAUSES = {
    errno.ENOSPC: ("no space left on the device: the disk is full", "free some space, or write elsewhere"),
    errno.EDQUOT: ("the disk quota is exceeded", "free some space or raise the quota, or write elsewhere"),
    errno.EROFS: ("the file system is read-only", "write into another folder"),
    errno.EACCES: ("permission denied", "write into another folder, or change the folder's permissions"),
    errno.EPERM: ("operation not permitted", "write into another folder, or change the folder's permissions"),
    errno.EFBIG: ("the file is too large for the file system", "write elsewhere"),
    errno.EIO: ("an input/output error of the device", "check the disk, or write elsewhere"),
}
"""The cause in words and the fix, by ``errno``, of the common write failures."""

_KINDS = (
    (stat.S_ISDIR, "a folder"),
    (stat.S_ISFIFO, "a named pipe (FIFO)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def describe(mode: int) -> str:
    """What a file of ``st_mode`` ``mode`` is, in words: ``"a regular file"``, ``"a folder"``, …"""
    if stat.S_ISREG(mode):
        return "a regular file"
    return next((kind for test, kind in _KINDS if test(mode)), "not a file")


def require_regular(path: str | os.PathLike, advice: str, *, missing_ok: bool = False) -> bool:
    """Check, without opening it, that ``path`` is a regular file (``os.stat`` and ``stat.S_ISREG``).

    Args:
        path: the file (a symbolic link is followed).
        advice: what to do, ending the message of a refusal (``"replace it by the dataset's file"``).
        missing_ok: return ``False`` for a path that does not exist instead of raising.

    Returns:
        ``True`` for a regular file; ``False`` for a missing one when ``missing_ok``.

    Raises:
        NotARegularFileError: ``path`` is a folder, a named pipe, a device or a socket.
        FileNotFoundError: ``path`` does not exist (a dangling link included), unless ``missing_ok``.
        OSError: ``path`` cannot be examined (a folder on the way that cannot be searched).
    """
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        if missing_ok:
            return False
        raise FileNotFoundError(errno.ENOENT, "no such file", os.fspath(path)) from None
    if not stat.S_ISREG(mode):
        raise NotARegularFileError(path, describe(mode), advice)
    return True


def open_regular(path: str | os.PathLike, advice: str, mode: str = "r", **kwargs: Any) -> IO:
    """``open(path, mode, **kwargs)`` for reading a file that must be a regular file.

    The path is checked by :func:`require_regular` first, then opened without blocking
    (``O_NONBLOCK``) and checked again on the open descriptor, so a path swapped for a named pipe
    in between is refused too rather than waited on.

    Raises:
        NotARegularFileError, FileNotFoundError: as :func:`require_regular`.
    """
    if any(c in mode for c in "wax+"):
        raise ValueError(f"open_regular reads files; mode {mode!r} writes")
    require_regular(path, advice)
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0))
    try:
        st_mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(st_mode):
            raise NotARegularFileError(path, describe(st_mode), advice)
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        return open(fd, mode, closefd=True, **kwargs)
    except BaseException:
        os.close(fd)
        raise


def _target(path: str | os.PathLike, advice: str) -> str:
    """The file a write of ``path`` replaces: ``path``, or the file its symbolic link points to."""
    try:
        require_regular(path, advice, missing_ok=True)  # os.stat follows the link: the message names ``path``
    except OSError as err:  # a folder on the way that cannot be searched, say
        raise FileWriteError(path, err) from None
    return os.path.realpath(path)


def _temporary(real: str, suffix: str) -> tuple[int, str]:
    """A new file (``O_EXCL``) beside ``real``, ``.NAME.<random>SUFFIX``, with the permissions a plain
    ``open(path, "w")`` would give (``0o666`` less the umask)."""
    folder, name = os.path.split(real)
    while True:
        tmp = os.path.join(folder, f".{name}.{secrets.token_hex(4)}{suffix}")
        try:
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666), tmp
        except FileExistsError:
            continue


def _unlink(path: str) -> None:
    try:
        os.unlink(path)
    except OSError:
        pass


def write_atomic(
    path: str | os.PathLike,
    write: Callable[[IO], None],
    *,
    binary: bool = False,
    make_folder: bool = False,
    note: str = "",
    not_regular_advice: str = "remove it, or write elsewhere",
) -> None:
    """Write ``path`` atomically: ``write(f)`` fills a temporary file beside it, which replaces ``path``.

    Args:
        path: the file to write.
        write: called with the temporary file open for writing (text in UTF-8, or bytes when ``binary``).
        binary: open the temporary file in binary mode.
        make_folder: create the folder of ``path`` (and its parents) when missing.
        note: what the message of a failed write ends with (what the caller keeps, how to go on).
        not_regular_advice: what to do when ``path`` exists and is not a regular file.

    Raises:
        NotARegularFileError: ``path`` exists and is a folder, a named pipe, a device or a socket
            (nothing is written).
        FileWriteError: the folder cannot be created, or the file cannot be written or renamed
            (``ENOSPC``, ``EDQUOT``, ``EROFS``, ``EACCES``, …); ``path`` is left as it was.
    """
    real = _target(path, not_regular_advice)
    try:
        if make_folder:
            os.makedirs(os.path.dirname(real), exist_ok=True)
        fd, tmp = _temporary(real, ".tmp")
    except OSError as err:
        raise FileWriteError(path, err, note) from None
    try:
        with open(fd, "wb" if binary else "w", **({} if binary else {"encoding": "utf-8"})) as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())  # a full disk can surface only now (delayed allocation)
        os.replace(tmp, real)
    except OSError as err:
        _unlink(tmp)
        raise FileWriteError(path, err, note) from None
    except BaseException:
        _unlink(tmp)
        raise


def write_atomic_path(
    path: str | os.PathLike,
    write: Callable[[str], None],
    *,
    note: str = "",
    not_regular_advice: str = "remove it, or write elsewhere",
) -> None:
    """Like :func:`write_atomic`, for a writer that takes a path (``savefig``): ``write(tmp)`` writes the
    temporary file, whose name ends as ``path`` does (``.png``: the format is taken from it).

    An error other than an ``OSError`` (an ``ImportError`` when matplotlib is missing) removes the
    temporary file and propagates unchanged.
    """
    real = _target(path, not_regular_advice)
    try:
        fd, tmp = _temporary(real, os.path.splitext(real)[1])
        os.close(fd)
    except OSError as err:
        raise FileWriteError(path, err, note) from None
    try:
        write(tmp)
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, real)
    except OSError as err:
        _unlink(tmp)
        raise FileWriteError(path, err, note) from None
    except BaseException:
        _unlink(tmp)
        raise
