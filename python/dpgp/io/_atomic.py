"""Atomic file writes: a temporary file beside the target, flushed to disk, then ``os.replace``,
so that an interrupted or failed write leaves any previous file intact. Model files and
checkpoints (:mod:`.modelfile`, :mod:`.checkpoint`) both write this way."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from typing import BinaryIO


def write_atomic(path: str, write: Callable[[BinaryIO], None]) -> None:
    """Call ``write`` on a temporary file beside ``path``, sync it and rename it onto ``path``
    (with the mode a plain ``open`` would give); on any failure the temporary file goes and
    ``path`` is untouched."""
    if os.path.isdir(path):
        raise IsADirectoryError(21, "a model file cannot replace a directory; give a file path", path)
    directory = os.path.dirname(os.path.abspath(path))
    _check_renames_allowed(directory, path)
    fd, tmp = tempfile.mkstemp(prefix=temp_prefix(path), suffix=".tmp", dir=directory)
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, _file_mode(path))
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


#: Linux inode flags (``chattr``): in an append-only or immutable directory a file can be
#: created (append-only) but neither renamed nor removed, so a temporary file could never go.
_FS_IOC_GETFLAGS, _FS_IMMUTABLE_FL, _FS_APPEND_FL = 0x80086601, 0x10, 0x20


def _check_renames_allowed(directory: str, path: str) -> None:
    """Refuse, before a temporary file exists, a directory where it could be neither renamed
    into place nor removed (``chattr +a`` / ``+i``): ``PermissionError`` naming it."""
    try:
        import fcntl
        import struct

        fd = os.open(directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except (ImportError, OSError):
        return  # not Linux, or a directory we cannot open: mkstemp says what is wrong
    try:
        flags = struct.unpack("l", fcntl.ioctl(fd, _FS_IOC_GETFLAGS, b"\0" * 8))[0]
    except OSError:
        return  # a file system without inode flags
    finally:
        os.close(fd)
    if flags & (_FS_IMMUTABLE_FL | _FS_APPEND_FL):
        kind = "immutable" if flags & _FS_IMMUTABLE_FL else "append-only"
        raise PermissionError(
            13,
            f"cannot write {path} atomically: its directory {directory} is {kind} (chattr), so a temporary file "
            "could be neither renamed into place nor removed; write elsewhere or clear the flag",
            path,
        )


def temp_prefix(path: str) -> str:
    """The prefix of ``save``'s temporary files for ``path``: named after it, so that the
    leftover of a writer killed mid-save (SIGKILL runs no cleanup) can be found and removed."""
    return f".dpgp-{os.path.basename(path)[:64]}-"


def _file_mode(path: str) -> int:
    """The mode a plain ``open(path, "w")`` would give (mkstemp's is 0600), or the old file's."""
    try:
        return os.stat(path).st_mode & 0o777
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask
