"""The C++/OpenMP kernels (projection, binning, compositing): lazy build, cache and ctypes binding.

The kernels (``csrc/*.cpp``) have a plain C ABI and include no torch or Python headers, so building them is one
compiler call of 1–3 s (``$CXX`` or ``g++``, ``-O3 -fopenmp -march=native``, retried without ``-march=native`` if the
compiler refuses it). The shared library is cached under the torch extensions directory (``$TORCH_EXTENSIONS_DIR`` or
torch's default, ``~/.cache/torch_extensions``) in ``spotlessgs_raster/``, named by a hash of the sources, the
compiler, its flags and the CPU model/features; it is written atomically, so concurrent first uses are safe. Any
build or load failure is logged once as a warning and ``backend="auto"`` falls back to the pure-torch backend
(:func:`load_kernel` returns None).
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import json
import logging
import os
import shutil
import subprocess
import threading
from dataclasses import dataclass
from pathlib import Path

from torch import Tensor

from spotlessgs.io.atomic import atomic_path, write_json

log = logging.getLogger(__name__)

SOURCES = tuple(Path(__file__).with_name("csrc") / name for name in ("composite.cpp", "projection.cpp", "binning.cpp"))
ABI_VERSION = 6  # must equal spotless_raster_abi_version() in the C++ source
CXX_FLAGS = ("-O3", "-std=c++17", "-fopenmp", "-fPIC", "-shared", "-fno-math-errno")
NATIVE_FLAG = "-march=native"  # tried first (AVX2/AVX-512 lanes); the build is retried without it if refused
_BUILD_TIMEOUT_S = 300

_lock = threading.Lock()
_cached: dict[str, object] = {}  # "kernel" → CppKernel, "error" → str


class KernelBuildError(RuntimeError):
    """The C++ kernel could not be compiled or loaded (the message says why)."""


@dataclass(frozen=True)
class CppKernel:
    """The loaded shared library and where it came from."""

    lib: ctypes.CDLL  # the loaded library
    path: Path  # the cached .so file


def cache_dir() -> Path:
    """Directory holding the compiled kernels (under the torch extensions directory)."""
    root = os.environ.get("TORCH_EXTENSIONS_DIR")
    if not root:
        from torch.utils.cpp_extension import get_default_build_root

        root = get_default_build_root()
    return Path(root) / "spotlessgs_raster"


def _compiler() -> str:
    cxx = os.environ.get("CXX") or shutil.which("g++") or shutil.which("c++")
    if not cxx:
        raise KernelBuildError("no C++ compiler found (set $CXX or install g++)")
    return cxx


def _cpu_signature() -> bytes:
    """The CPU model and feature flags: a -march=native build is only reused on the same kind of CPU."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        import platform

        return platform.processor().encode()
    keep = [ln for ln in lines if ln.startswith(("model name", "flags", "Features", "CPU part"))]
    return "\n".join(sorted(set(keep))).encode()


def _library_path(cxx: str) -> Path:
    try:
        version = subprocess.run([cxx, "--version"], capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.SubprocessError) as exc:
        raise KernelBuildError(f"cannot run the C++ compiler {cxx!r}: {exc}") from exc
    digest = hashlib.sha256()
    sources = [src.read_bytes() for src in SOURCES]
    for part in (*sources, cxx.encode(), version.encode(), " ".join(CXX_FLAGS).encode(), _cpu_signature(),
                 b"with-flags-record"):  # builds that record their flags (numerics_record) get their own name
        digest.update(part)
        digest.update(b"\0")
    return cache_dir() / f"composite_{digest.hexdigest()[:16]}.so"


def build_kernel() -> Path:
    """Compile the kernel into the cache if it is not there yet; returns the library path.

    Raises:
        KernelBuildError: no compiler, or the compiler failed (its output is in the message).
    """
    cxx = _compiler()
    target = _library_path(cxx)
    if target.is_file():
        return target
    with atomic_path(target) as tmp:
        error = ""
        for flags in ((*CXX_FLAGS, NATIVE_FLAG), CXX_FLAGS):
            cmd = [cxx, *flags, *(str(src) for src in SOURCES), "-o", str(tmp)]
            try:
                proc = subprocess.run(cmd, capture_output=True, text=True, timeout=_BUILD_TIMEOUT_S)
            except (OSError, subprocess.SubprocessError) as exc:
                raise KernelBuildError(f"running {' '.join(cmd)} failed: {exc}") from exc
            if proc.returncode == 0:
                break
            error = f"{' '.join(cmd)} exited with {proc.returncode}:\n{proc.stderr.strip()}"
        else:
            raise KernelBuildError(error)
    write_json(_flags_path(target), {"flags": list(flags)})
    return target


def _flags_path(library: Path) -> Path:
    return library.with_suffix(".flags.json")


def numerics_record(num_threads: int | None, device: str = "cpu") -> dict[str, object]:
    """What a CPU run's floating-point results depend on besides its code, data and seed (docs/results.md,
    "Determinism"): the CPU model, torch's CPU kernel level, the C++ kernel's build flags (``-march=native`` lets the
    compiler fuse multiply-adds where the CPU has FMA) and the thread count. Two runs that agree on all of these give
    bit-identical results; a change in any of them changes the last bits, and training amplifies that."""
    import platform

    import torch

    cpu = next((line.split(":", 1)[1].strip() for line in _cpu_signature().decode(errors="replace").splitlines()
                if line.startswith("model name")), platform.processor() or None)
    flags = None
    kernel = load_kernel() if device == "cpu" else None  # built once per machine, used by the CPU rasterizer anyway
    if kernel is not None:
        with contextlib.suppress(OSError, ValueError):
            flags = json.loads(_flags_path(kernel.path).read_text())["flags"]
    return {"cpu": cpu, "torch_cpu_capability": torch.backends.cpu.get_cpu_capability(),
            "kernel_flags": flags, "threads": num_threads}


def _bind(path: Path) -> CppKernel:
    lib = ctypes.CDLL(str(path))
    lib.spotless_raster_abi_version.restype = ctypes.c_int
    found = lib.spotless_raster_abi_version()
    if found != ABI_VERSION:
        raise KernelBuildError(f"{path}: kernel ABI version {found}, expected {ABI_VERSION}")
    ptr, i64, cint, dbl = ctypes.c_void_p, ctypes.c_int64, ctypes.c_int, ctypes.c_double
    for suffix in ("f32", "f64"):
        fwd = getattr(lib, f"spotless_composite_forward_{suffix}")
        fwd.argtypes = [ptr] * 6 + [i64] * 6 + [ptr] * 3 + [cint]
        fwd.restype = None
        bwd = getattr(lib, f"spotless_composite_backward_{suffix}")
        bwd.argtypes = [ptr] * 6 + [i64] * 6 + [ptr] * 5 + [cint]
        bwd.restype = None
        red = getattr(lib, f"spotless_reduce_pairs_{suffix}")
        red.argtypes = [ptr, ptr, i64, i64, ptr]
        red.restype = None
        pf = getattr(lib, f"spotless_project_forward_{suffix}")
        pf.argtypes = [ptr] * 6 + [i64] * 3 + [dbl] * 4 + [ptr] * 5 + [cint]
        pf.restype = None
        pb = getattr(lib, f"spotless_project_backward_{suffix}")
        pb.argtypes = [ptr] * 5 + [i64] * 3 + [dbl] * 3 + [ptr] * 6 + [cint]
        pb.restype = None
        bc = getattr(lib, f"spotless_bin_count_{suffix}")
        bc.argtypes = [ptr] * 3 + [i64] * 4 + [ptr] * 2
        bc.restype = i64
        bf = getattr(lib, f"spotless_bin_fill_{suffix}")
        bf.argtypes = [ptr] * 3 + [i64] * 4 + [ptr] * 2
        bf.restype = None
    return CppKernel(lib=lib, path=path)


def load_kernel(*, raise_errors: bool = False) -> CppKernel | None:
    """The compiled kernel, building it on first use; None (after one logged warning) if that fails.

    Args:
        raise_errors: raise :class:`KernelBuildError` instead of returning None.
    """
    with _lock:
        if "kernel" in _cached:
            return _cached["kernel"]  # type: ignore[return-value]
        if "error" not in _cached:
            try:
                _cached["kernel"] = _bind(build_kernel())
                return _cached["kernel"]  # type: ignore[return-value]
            except (KernelBuildError, OSError, AttributeError) as exc:
                _cached["error"] = str(exc)
                log.warning("C++ rasterizer kernel unavailable, using the pure-torch backend: %s", exc)
        if raise_errors:
            raise KernelBuildError(str(_cached["error"]))
        return None


def kernel_error() -> str | None:
    """Why the last :func:`load_kernel` failed, or None."""
    return _cached.get("error")  # type: ignore[return-value]


def pointer(t: Tensor) -> ctypes.c_void_p:
    """The data pointer of a contiguous CPU tensor, for a kernel call."""
    return ctypes.c_void_p(t.data_ptr())


__all__ = ["ABI_VERSION", "CppKernel", "KernelBuildError", "SOURCES", "build_kernel", "cache_dir",
           "kernel_error", "load_kernel", "pointer"]
