"""Files of ``state_dir`` that are what they seem (no rclpy): private directories and files
(0700 / 0600 whatever the umask), opened without following symlinks, required to be regular
files, read with a bound; and the exclusive lock that makes one node the only writer of a
``state_dir``.

A journal or snapshot path that is a symlink, FIFO, device or directory is refused with
:class:`NotARegularFile` (a ``ValueError`` naming the path and what it is): a symlink would get
another file truncated and appended to, a FIFO hangs a blocking open, ``/dev/zero`` never ends.
"""

from __future__ import annotations

import errno
import fcntl
import os
import stat
from typing import Optional
from ..core.errors import InputError
from .state_dir import LOCK_NAME

#: Files of ``state_dir`` are created with these permissions (the umask cannot widen them, and
#: they are set again with ``fchmod``/``chmod`` so a restrictive umask cannot narrow them either).
FILE_MODE = 0o600
DIR_MODE = 0o700


class NotARegularFile(InputError):
    """A ``state_dir`` file that is a symlink, FIFO, device or directory."""


class StateDirBusy(InputError):
    """Another process (or node) holds the lock of ``state_dir``."""


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISLNK, "a symlink"), (stat.S_ISDIR, "a directory"),
                       (stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def check_regular(path: str) -> bool:
    """Whether ``path`` exists; it must then be a regular file (not followed if a symlink).

    :raises NotARegularFile: naming the path and what it is.
    """
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return False
    if not stat.S_ISREG(mode):
        raise NotARegularFile(f"{path} is {_kind(mode)}, not a regular file: refused (move it "
                              f"away)")
    return True


def private_dir(path: str) -> str:
    """Create directory ``path`` (and parents) if missing, the leaf with mode 0700.

    :return: the absolute path.
    :raises OSError: when it cannot be created (e.g. a file of that name, read-only parent).
    """
    path = os.path.abspath(os.path.expanduser(path))
    if os.path.lexists(path) and not os.path.isdir(path):
        raise NotADirectoryError(errno.ENOTDIR, "exists and is not a directory", path)
    if not os.path.isdir(path):
        os.makedirs(path, mode=DIR_MODE, exist_ok=True)
        os.chmod(path, DIR_MODE)
    return path


def open_private(path: str, flags: int) -> int:
    """``os.open`` a regular file without following symlinks and without blocking on a FIFO;
    a file it creates gets mode 0600 whatever the umask.

    :raises NotARegularFile: when ``path`` is a symlink, FIFO, device or directory.
    :raises OSError: other open errors.
    """
    existed = check_regular(path)
    try:
        fd = os.open(path, flags | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC, FILE_MODE)
    except OSError as exc:
        if exc.errno in (errno.ELOOP, errno.EISDIR, errno.ENXIO):
            check_regular(path)   # replaced between the check and the open: name what it is
        raise
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise NotARegularFile(f"{path} is {_kind(st.st_mode)}, not a regular file: refused")
        if not existed or stat.S_IMODE(st.st_mode) != FILE_MODE:
            os.fchmod(fd, FILE_MODE)
        fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) & ~os.O_NONBLOCK)
    except BaseException:
        os.close(fd)
        raise
    return fd


def check_input_file(path: str, limit: int) -> None:
    """A file the user names as input (a symlink to one is fine): it must be a regular file of
    at most ``limit`` bytes (``/dev/zero`` as a CSV read until memory ran out).

    :raises FileNotFoundError: when it does not exist.
    :raises NotARegularFile: naming the path and what it is, or its size over the limit.
    """
    st = os.stat(path)
    if not stat.S_ISREG(st.st_mode):
        raise NotARegularFile(f"{path} is {_kind(st.st_mode)}, not a regular file: refused")
    if st.st_size > limit:
        raise NotARegularFile(f"{path} is {st.st_size} bytes, more than the limit of {limit}: "
                              f"refused")


def read_fd(fd: int, path: str, limit: int) -> bytes:
    """Read the whole regular file open as ``fd`` from offset 0, at most ``limit`` bytes.

    :raises ValueError: when the file is larger than ``limit``.
    """
    size = os.fstat(fd).st_size
    if size > limit:
        raise ValueError(f"{path} is {size} bytes, more than the limit of {limit}: refused")
    return pread_range(fd, 0, size)


def pread_range(fd: int, start: int, end: int) -> bytes:
    """Bytes ``start`` to ``end`` of the file open as ``fd``, read in 1 MiB chunks (fewer at
    its end)."""
    chunks, offset = [], start
    while offset < end:
        chunk = os.pread(fd, min(1 << 20, end - offset), offset)
        if not chunk:
            break
        chunks.append(chunk)
        offset += len(chunk)
    return b"".join(chunks)


def read_regular(path: str, limit: int) -> bytes:
    """The content of regular file ``path`` (see :func:`open_private`, :func:`read_fd`)."""
    fd = open_private(path, os.O_RDONLY)
    try:
        return read_fd(fd, path, limit)
    finally:
        os.close(fd)


class StateDirLock:
    """An exclusive ``flock`` on ``state_dir/lock``, held until :meth:`release`: one writer per
    ``state_dir`` (another process or another node of this process is refused). The lock file
    holds the holder's pid, for the refusal message; the kernel drops the lock when the
    holder dies, however it dies.

    :raises StateDirBusy: naming the directory and the holder's pid.
    :raises OSError: when the lock file cannot be created.
    """

    def __init__(self, state_dir: str) -> None:
        self._fd: Optional[int] = None
        self.state_dir = private_dir(state_dir)
        self.path = os.path.join(self.state_dir, LOCK_NAME)
        self._fd = open_private(self.path, os.O_RDWR | os.O_CREAT)
        try:
            fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(self._fd, 32, 0).decode("ascii", "replace").strip() or "unknown"
            self.release()
            raise StateDirBusy(f"state_dir {self.state_dir} is in use by another node (pid "
                               f"{holder}, lock {self.path}): one writer per state_dir; stop "
                               f"that node or choose another state_dir") from None
        except BaseException:
            self.release()
            raise
        os.ftruncate(self._fd, 0)
        os.pwrite(self._fd, f"{os.getpid()}\n".encode("ascii"), 0)

    def release(self) -> None:
        """Drop the lock (idempotent)."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def __del__(self) -> None:
        self.release()
