"""The compiled regressor kernel: build the generated C++, cache it on disk, call it.

`torchjfa.dynamics._codegen` writes the C++ source of one robot's regressor; this module
compiles it with the system C++ compiler (``CXX`` or ``g++``, ``-O2 -march=native``) into a
shared library cached on disk under ``$TORCHJFA_CACHE_DIR`` (default ``~/.cache/torchjfa``),
keyed by the source, the compiler and the CPU, and calls it through ctypes; ctypes releases the
GIL, so ``torch.get_num_threads()`` threads each take a slice of the batch.
`RigidBodyModel.regressor(..., compiled=True)` holds one `RegressorKernel` per dtype.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import shutil
import subprocess
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import torch

from .._util import note
from ._codegen import LANES, kernel_source
from ._tree import KinematicTree

__all__ = ["RegressorKernel", "build_kernel", "cache_dir"]

_MIN_PER_THREAD = 2048  # samples; below this one thread does the whole batch
_BUILD_LOCK = threading.Lock()


def cache_dir() -> Path:
    """Where compiled kernels are kept: ``$TORCHJFA_CACHE_DIR`` or ``~/.cache/torchjfa``."""
    env = os.environ.get("TORCHJFA_CACHE_DIR")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "torchjfa"


def _compiler() -> str:
    for cand in (os.environ.get("CXX"), "g++", "c++", "clang++"):
        if cand and shutil.which(cand):
            return cand
    raise RuntimeError(
        "compiled=True needs a C++ compiler (set CXX, or install g++): none of CXX, g++, c++, "
        "clang++ is on PATH; use compiled=False (the torch path)"
    )


def _cpu_signature() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith(("flags", "Features")):
                    return line
    except OSError:
        pass
    return platform.processor() + platform.machine()


def _run(cmd: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, capture_output=True, text=True, check=False)


def _compile(source: str) -> tuple[Path, bool]:
    """Compile ``source`` to a shared library (cached); returns its path and whether cached."""
    cxx = _compiler()
    version = _run([cxx, "--version"]).stdout.splitlines()[:1]
    flag_sets = (["-O2", "-march=native"], ["-O2"])
    key = hashlib.sha256(
        "\n".join([source, cxx, *version, repr(flag_sets), _cpu_signature()]).encode()
    ).hexdigest()[:24]
    folder = cache_dir()
    lib = folder / f"regressor_{key}.so"
    if lib.is_file():
        return lib, True
    note(
        f"compiling the regressor kernel for this robot with {cxx} (a few seconds, once per "
        f"robot, dtype and machine; cached in {folder})"
    )
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:  # an unwritable cache: build in a fresh temporary folder instead
        folder = Path(tempfile.mkdtemp(prefix="torchjfa-kernels-"))
        lib = folder / lib.name
    with tempfile.TemporaryDirectory(dir=folder) as tmp:
        cpp = Path(tmp) / "kernel.cpp"
        cpp.write_text(source, encoding="utf-8")
        out = Path(tmp) / "kernel.so"
        errors = []
        for flags in flag_sets:
            res = _run([cxx, *flags, "-shared", "-fPIC", "-std=c++14", "-o", str(out), str(cpp)])
            if res.returncode == 0:
                break
            errors.append(f"{' '.join([cxx, *flags])}: {res.stderr.strip()[-2000:]}")
        else:
            raise RuntimeError(
                "compiling the regressor kernel failed; use compiled=False.\n" + "\n".join(errors)
            )
        os.replace(out, lib)  # atomic: concurrent builders write the same bytes
    return lib, False


# ----------------------------------------------------------------------------- the kernel
_POOL: ThreadPoolExecutor | None = None
_POOL_SIZE = 0


def _pool(threads: int) -> ThreadPoolExecutor:
    global _POOL, _POOL_SIZE
    with _BUILD_LOCK:
        if _POOL is None or _POOL_SIZE < threads:
            if _POOL is not None:
                _POOL.shutdown(wait=True)
            _POOL, _POOL_SIZE = ThreadPoolExecutor(threads, "torchjfa-regressor"), threads
        return _POOL


class RegressorKernel:
    """A compiled regressor for one robot, friction layout and dtype (CPU).

    Attributes:
        dtype: torch.float64 or torch.float32.
        build_seconds: wall time to generate and compile (or load from the disk cache).
        from_cache: True when the shared library was found in `cache_dir`.
        path: the shared library.
    """

    def __init__(self, tree: KinematicTree, friction: tuple[str, ...], dtype: torch.dtype):
        t0 = time.perf_counter()
        self.dtype = dtype
        self.n = len(tree.parent)
        self.ncol = self.n * self.n * (10 + len(friction))
        with _BUILD_LOCK:
            self.path, self.from_cache = _compile(kernel_source(tree, friction, dtype))
        self._load()
        self.build_seconds = time.perf_counter() - t0

    def _load(self) -> None:
        self._lib = ctypes.CDLL(str(self.path))
        fn = self._lib.regressor
        fn.restype = None
        fn.argtypes = [ctypes.c_void_p] * 6 + [ctypes.c_int64]
        self._fn = fn

    def __getstate__(self) -> dict:  # copy/pickle: the library is loaded again from its path
        state = dict(self.__dict__)
        del state["_lib"], state["_fn"]
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._load()

    def __call__(
        self, out: torch.Tensor, q: torch.Tensor, qd: torch.Tensor, qdd: torch.Tensor
    ) -> torch.Tensor:
        """Fill ``out`` ``(B, n, n_params)`` (contiguous, CPU, `dtype`) from ``(B, n)`` states."""
        B = q.shape[0]
        q, qd, qdd = (v.contiguous() for v in (q, qd, qdd))
        with torch.no_grad():
            sn, cs = torch.sin(q), torch.cos(q)
        arrays = (q, qd, qdd, sn, cs, out)
        size = q.element_size()
        rows = (self.n,) * 5 + (self.ncol,)
        threads = max(1, min(torch.get_num_threads(), B // _MIN_PER_THREAD))
        if threads == 1:
            self._fn(*(a.data_ptr() for a in arrays), B)
            return out
        step = -(-B // threads)
        step += -step % LANES[self.dtype]

        def part(s0: int) -> None:
            cnt = min(B, s0 + step) - s0
            self._fn(
                *(a.data_ptr() + s0 * r * size for a, r in zip(arrays, rows, strict=True)), cnt
            )

        for f in [_pool(threads).submit(part, s0) for s0 in range(0, B, step)]:
            f.result()
        return out


def build_kernel(tree: KinematicTree, friction: tuple[str, ...], dtype) -> RegressorKernel:
    """Generate, compile (or load from the disk cache) and load the kernel."""
    return RegressorKernel(tree, tuple(friction), dtype)
