"""Locate a libLLVM that Dr.Jit's LLVM backend can use, and pick a Mitsuba variant.

Dr.Jit's LLVM backend needs libLLVM >= 16 (libLLVM 15 crashes at JIT time
with ``Cannot select ... fminimum``).  Dr.Jit reads ``DRJIT_LIBLLVM_PATH``
when it is first imported, so this module must run before ``drjit`` is
imported; ``corona/__init__.py`` imports it first.

Side effect of ``import corona`` (the one change it makes to the process's
global state): when ``DRJIT_LIBLLVM_PATH`` is unset, it is set in
``os.environ`` to the newest libLLVM >= 16 found on the usual system paths;
a value the user set is never changed.  Nothing else is written (no variant
is activated on import).
"""
from __future__ import annotations

import glob
import os
import re
import sys
import warnings

MIN_LLVM_MAJOR = 16

_SEARCH_PATTERNS = (
    "/usr/lib/x86_64-linux-gnu/libLLVM*.so*",
    "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/usr/lib64/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
    "/opt/homebrew/opt/llvm/lib/libLLVM.dylib",
    "/usr/local/opt/llvm/lib/libLLVM.dylib",
)

FIX_HINT = ("install libLLVM >= 16 (on Debian/Ubuntu: `apt-get install -y libllvm19`) "
            "or point DRJIT_LIBLLVM_PATH at it")


def llvm_major(path: str) -> int | None:
    """The LLVM major version encoded in a library file name, or None."""
    name = os.path.basename(path)
    m = re.search(r"libLLVM[-.]?(?:so\.)?(\d+)", name)
    if m is None:
        m = re.search(r"llvm-(\d+)", path)
    return int(m.group(1)) if m else None


def find_libllvm(min_major: int = MIN_LLVM_MAJOR) -> str | None:
    """Path of the newest libLLVM with major version >= ``min_major``, or None."""
    best: tuple[int, str] | None = None
    for pattern in _SEARCH_PATTERNS:
        for path in glob.glob(pattern):
            major = llvm_major(path)
            if major is None or major < min_major or not os.path.isfile(path):
                continue
            if best is None or major > best[0]:
                best = (major, path)
    return best[1] if best else None


def configure_llvm() -> str | None:
    """Set ``DRJIT_LIBLLVM_PATH`` to a suitable libLLVM unless the user set it.

    Returns the path in use, or None when none was found.
    """
    current = os.environ.get("DRJIT_LIBLLVM_PATH")
    if current:
        return current
    path = find_libllvm()
    if path is not None:
        if "drjit" in sys.modules:
            warnings.warn("drjit was imported before corona: DRJIT_LIBLLVM_PATH=%s may be "
                          "ignored; import corona first" % path, RuntimeWarning, stacklevel=3)
        os.environ["DRJIT_LIBLLVM_PATH"] = path
    return path


LIBLLVM_PATH = configure_llvm()

_warned_fallback = False


def available_variants() -> list[str]:
    import mitsuba as mi
    return list(mi.variants())


def has_cuda() -> bool:
    """True if Dr.Jit's CUDA backend can run here."""
    try:
        import drjit as dr
        return bool(dr.has_backend(dr.JitBackend.CUDA))
    except Exception:  # pragma: no cover - depends on the machine
        return False


def has_llvm() -> bool:
    """True if Dr.Jit's LLVM backend is usable with a libLLVM >= 16."""
    path = os.environ.get("DRJIT_LIBLLVM_PATH") or LIBLLVM_PATH
    if path is None:
        return False
    major = llvm_major(path)
    if major is not None and major < MIN_LLVM_MAJOR:
        return False
    try:
        import drjit as dr
        return bool(dr.has_backend(dr.JitBackend.LLVM))
    except Exception:  # pragma: no cover
        return False


def default_variant(prefer_gpu: bool = True) -> str:
    """The fastest spectral variant that works here: cuda > llvm > scalar.

    Falls back to ``scalar_spectral`` with one warning that says how to fix it.
    """
    global _warned_fallback
    variants = available_variants()
    if prefer_gpu and "cuda_ad_spectral" in variants and has_cuda():
        return "cuda_ad_spectral"
    if "llvm_ad_spectral" in variants and has_llvm():
        return "llvm_ad_spectral"
    if not _warned_fallback:
        warnings.warn("corona: no usable libLLVM >= 16 found; falling back to the slow "
                      "'scalar_spectral' variant. To fix: " + FIX_HINT, RuntimeWarning, stacklevel=2)
        _warned_fallback = True
    return "scalar_spectral"


def set_default_variant(prefer_gpu: bool = True) -> str:
    """Activate :func:`default_variant` in Mitsuba and return its name."""
    import mitsuba as mi
    v = default_variant(prefer_gpu)
    mi.set_variant(v)
    return v
