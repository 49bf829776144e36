"""The package's runtime helpers: torch's threads around small-matrix work, progress bars,
one-line notes to the user, and results written whole.

- `single_thread`: torch (and its BLAS) on one thread inside a block.
- `progress_bar`: a tqdm bar, off by default in the library, on in scripts.
- `note`: a note (a kernel being compiled, a fast path falling back) to the ``"torchjfa"``
  logger at INFO level, each distinct note once per process. When nobody has configured
  logging (the root logger has no handler), that logger prints them to stderr as ``torchjfa:
  <note>``, as Lightning does for its own messages; silence them with
  ``logging.getLogger("torchjfa").setLevel(logging.WARNING)`` or route them with any handler.
- `output_folder`, `atomic_file`, `output_lock`, `check_output`: result folders and files that
  a killed run leaves either whole (the new result) or untouched (the old one); see
  `torchjfa.io`.
"""

from __future__ import annotations

import ctypes
import hashlib
import json
import logging
import os
import shutil
import sys
import tempfile
import threading
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

import torch
from tqdm import tqdm

__all__ = [
    "MANIFEST",
    "OutputError",
    "atomic_file",
    "check_output",
    "library_version",
    "note",
    "output_folder",
    "output_lock",
    "progress_bar",
    "single_thread",
]


@contextmanager
def single_thread() -> Iterator[None]:
    """Run torch (and its BLAS) on one thread inside the block, then restore the setting.

    For work made of many small ops: the projection's ~100 x 100 matrices, the eager
    regressor's ops on one chunk of samples. Threads cannot speed such ops up, and where other
    work shares the cores each op waits for its slowest thread, so that a 100 x 100
    matrix-vector product can become many times slower (scikit-learn limits BLAS threads
    around such work for the same reason). The setting is process-wide,
    so other Python threads running torch meanwhile get one thread too.
    """
    threads = torch.get_num_threads()
    if threads == 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def progress_bar(*, total: int | None, desc: str, enabled: bool, unit: str = "it"):
    """A tqdm bar, or a do-nothing bar when ``enabled`` is False.

    Use as a context manager and call ``bar.update(k)``; ``bar.set_postfix(...)`` works too.
    """
    return tqdm(
        total=total, desc=desc, disable=not enabled, unit=unit, leave=False, dynamic_ncols=True
    )


_logger = logging.getLogger("torchjfa")
_seen: set[str] = set()
_lock = threading.Lock()


def _ensure_handler() -> None:
    if _logger.handlers or logging.getLogger().handlers:
        return
    handler = logging.StreamHandler()  # stderr, resolved at emit time
    handler.setFormatter(logging.Formatter("torchjfa: %(message)s"))
    _logger.addHandler(handler)
    _logger.propagate = False
    if _logger.level == logging.NOTSET:
        _logger.setLevel(logging.INFO)


def note(message: str, *, key: str | None = None) -> None:
    """Tell the user ``message`` once per process (per ``key``, default the message)."""
    with _lock:
        k = message if key is None else key
        if k in _seen:
            return
        _seen.add(k)
        _ensure_handler()
    _logger.info(message)


#: the file a result folder names its run and its files in, written last
MANIFEST = "manifest.json"


class OutputError(ValueError):
    """An output path the library will not write: a file where a folder belongs, a symbolic
    link, a folder holding files the library did not write, or one another run is writing."""


def _staging_prefix(out: Path) -> str:
    return f".{out.name}.partial-"


def _lock_path(out: Path) -> Path:
    return out.parent / f".{out.name}.lock"


_held: dict[str, tuple[int, int]] = {}  # lock path -> (file descriptor, depth) in this process
_held_guard = threading.Lock()


def _flock(fd: int) -> bool:
    """An exclusive lock on ``fd`` without waiting; False where another process holds it."""
    try:
        import fcntl
    except ImportError:  # no advisory locks (Windows): concurrent runs are not detected
        return True
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    return True


@contextmanager
def output_lock(path: str | os.PathLike) -> Iterator[None]:
    """Hold the lock of the output ``path`` (a folder or a file) inside the block.

    The lock is an advisory lock on a hidden file beside it (``.<name>.lock``), released when
    the block ends or the process dies, however it dies. The same process may take it again
    inside the block (a command holds it for its whole run, the library's writer again).

    Raises:
        OutputError: another process holds it (a second run writing the same result).
    """
    out = Path(os.path.abspath(os.fspath(path)))
    out.parent.mkdir(parents=True, exist_ok=True)
    key = os.fspath(_lock_path(out))
    with _held_guard:
        if key in _held:
            fd, depth = _held[key]
            _held[key] = (fd, depth + 1)
        else:
            fd = os.open(key, os.O_RDWR | os.O_CREAT, 0o644)
            if not _flock(fd):
                os.close(fd)
                raise OutputError(
                    f"another run is writing {os.fspath(path)!r} (it holds {key!r}); wait for "
                    "it to end, or write to another path"
                )
            _held[key] = (fd, 1)
    try:
        yield
    finally:
        with _held_guard:
            fd, depth = _held[key]
            if depth == 1:
                del _held[key]
                os.close(fd)  # releases the lock; the empty lock file stays (removing it races)
            else:
                _held[key] = (fd, depth - 1)


def _written_by_us(out: Path) -> set[str]:
    """The names ``out``'s manifest lists (empty where it has none or cannot be read)."""
    try:
        manifest = json.loads((out / MANIFEST).read_text(encoding="utf-8"))
        names = [*manifest["files"], *manifest.get("folders", ())]
        return {str(name) for name in names} | {MANIFEST}
    except (OSError, ValueError, KeyError, TypeError):
        return set()


def check_output(path: str | os.PathLike, *, folder: bool = True, overwrite: bool = False) -> None:
    """Refuse an output path before any work is done on it.

    Args:
        path: where a result goes.
        folder: a result folder (else a single file).
        overwrite: replace a folder even where it holds files the library did not write.

    Raises:
        OutputError: ``path`` is a symbolic link; a file where a folder belongs, or a folder
            where a file belongs; or a folder holding files that its manifest does not list
            (not a result of this library) and ``overwrite`` is False.
    """
    out = Path(os.fspath(path))
    if out.is_symlink():
        raise OutputError(
            f"{os.fspath(path)!r} is a symbolic link, which is not followed: give the path it "
            "points to"
        )
    if not folder:
        if out.is_dir():
            raise OutputError(f"{os.fspath(path)!r} is a folder; give a file name")
        return
    if out.exists() and not out.is_dir():
        raise OutputError(f"{os.fspath(path)!r} is a file; give a folder for the results")
    if not out.is_dir() or overwrite:
        return
    ours = _written_by_us(out)
    foreign = sorted(p.name for p in out.iterdir() if p.name not in ours)
    if foreign:
        shown = ", ".join(foreign[:3]) + (
            f" and {len(foreign) - 3} more" if len(foreign) > 3 else ""
        )
        raise OutputError(
            f"{os.fspath(path)!r} holds files this library did not write ({shown}): choose "
            "another folder, or replace it whole with overwrite (--overwrite), which deletes them"
        )


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _input_hashes(inputs: Iterable[str | os.PathLike]) -> dict[str, str | None]:
    """Absolute path -> sha256 of each input file (None for a folder or what cannot be read)."""
    hashes: dict[str, str | None] = {}
    for p in inputs:
        path = Path(os.path.abspath(os.fspath(p)))
        try:
            hashes[os.fspath(path)] = _sha256(path) if path.is_file() else None
        except OSError:
            hashes[os.fspath(path)] = None
    return hashes


def library_version() -> str:
    """The installed torchjfa's version (its distribution's metadata, as ``pip`` has it), or
    ``"unknown"`` when it runs from a source tree that was never installed."""
    import importlib.metadata

    try:
        return importlib.metadata.version("torchjfa")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths in one atomic step (Linux ``renameat2(RENAME_EXCHANGE)``); False where
    the system cannot, so that the caller renames in two steps."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    if renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    errno = ctypes.get_errno()
    if errno in (22, 38, 95):  # EINVAL, ENOSYS, EOPNOTSUPP: the file system cannot swap
        return False
    raise OSError(errno, os.strerror(errno), os.fspath(b))


def _umask_mode(mode: int) -> int:
    """``mode`` less the process's umask: what ``mkdir`` or ``open`` would give (``mkdtemp``
    and ``mkstemp`` make private 0700/0600 entries)."""
    umask = os.umask(0)
    os.umask(umask)
    return mode & ~umask


def _remove_stale(out: Path) -> None:
    """Remove staging folders of ``out`` that earlier runs, killed, left behind (the caller
    holds the lock, so no live run owns them)."""
    for p in out.parent.glob(_staging_prefix(out) + "*"):
        shutil.rmtree(p, ignore_errors=True)


@contextmanager
def output_folder(
    path: str | os.PathLike,
    *,
    overwrite: bool = False,
    inputs: Iterable[str | os.PathLike] = (),
    command: str = "",
) -> Iterator[Path]:
    """Write a result folder as one unit: yields an empty staging folder beside ``path`` to
    write every file into; when the block ends without an error, a manifest (`MANIFEST`: the
    library's version, ``command``, each input's SHA-256, each file's size and SHA-256) is
    written last and the staging folder takes ``path``'s place in one rename (an atomic swap
    where an earlier result is there, on Linux). On an error or an interrupt the staging folder
    is removed and ``path`` is as it was: a killed run leaves the complete earlier result or the
    complete new one, never a mix, and the earlier run's files never stay beside the new ones.

    Args:
        path: the result folder.
        overwrite: replace ``path`` even where it holds files the library did not write.
        inputs: files the result was computed from, hashed into the manifest.
        command: the command line that made the result, for the manifest.

    Raises:
        OutputError: see `check_output` and `output_lock`.
    """
    out = Path(os.path.abspath(os.fspath(path)))
    with output_lock(out):
        check_output(path, overwrite=overwrite)
        _remove_stale(out)
        staging = Path(tempfile.mkdtemp(prefix=_staging_prefix(out), dir=out.parent))
        os.chmod(staging, _umask_mode(0o777))
        try:
            yield staging
            files = {
                p.name: {"bytes": p.stat().st_size, "sha256": _sha256(p)}
                for p in sorted(staging.iterdir())
                if p.is_file() and p.name != MANIFEST
            }
            manifest = {
                "written_by": f"torchjfa {library_version()}",
                "command": command,
                "inputs": _input_hashes(inputs),
                "files": files,
                "folders": sorted(p.name for p in staging.iterdir() if p.is_dir()),
            }
            (staging / MANIFEST).write_text(json.dumps(manifest, indent=1), encoding="utf-8")
            if not out.exists():
                os.rename(staging, out)
            elif _exchange(staging, out):
                pass  # the earlier result now lies at ``staging``, removed below
            else:
                old = Path(tempfile.mkdtemp(prefix=_staging_prefix(out), dir=out.parent))
                os.rename(out, old / "old")
                os.rename(staging, out)
                staging = old
        finally:
            shutil.rmtree(staging, ignore_errors=True)


@contextmanager
def atomic_file(path: str | os.PathLike) -> Iterator[Path]:
    """Write one file whole or not at all: yields a temporary path beside ``path`` (same
    suffix) to write to, renamed onto ``path`` when the block ends without an error, removed
    otherwise. Two runs writing the same file each leave a whole one (the last rename wins).

    Raises:
        OutputError: ``path`` is a folder or a symbolic link.
    """
    check_output(path, folder=False)
    out = Path(os.path.abspath(os.fspath(path)))
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=_staging_prefix(out), suffix=out.suffix, dir=out.parent)
    os.close(fd)
    os.chmod(tmp, _umask_mode(0o666))
    try:
        yield Path(tmp)
        os.replace(tmp, out)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
