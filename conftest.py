"""pytest setup shared by tests/ and the doctests of src/corona (see testpaths in pyproject.toml)."""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "scripts"))
import suite_cache  # noqa: E402  (scripts/suite_cache.py)

# Tables built by the tests and the doctests go to the tests' cache, never the user's: one
# folder per fingerprint of the code that builds tables, outside the clone and kept between
# runs, so a run builds each table once and a later run of the same code reads them back
# (scripts/suite_cache.py says what the fingerprint holds; CORONA_TEST_CACHE moves the root;
# `make clean-cache` deletes it).  It replaces any CORONA_CACHE_DIR of the environment: a cache
# keyed by parameters alone could serve a table of older code.  The xdist workers inherit it.
os.environ["CORONA_CACHE_DIR"] = suite_cache.folder()
os.environ.setdefault("NUMBA_CACHE_DIR", os.path.join(suite_cache.root(), "numba"))
suite_cache.prune()
# glibc hands every freed block above its mmap threshold (a few MB) back to the kernel and faults
# fresh pages in for the next large array; on small virtual machines those page faults cost more
# than the arithmetic.  The xdist workers and the commands the tests start (they read the
# environment at their start) keep large blocks in their heap instead: the system CPU time of the
# suite falls several-fold, nothing computed changes (benchmarks/results/suite_times.json).
os.environ.setdefault("MALLOC_MMAP_THRESHOLD_", str(1 << 30))
os.environ.setdefault("MALLOC_TRIM_THRESHOLD_", str(1 << 29))

import corona  # noqa: E402,F401  (sets DRJIT_LIBLLVM_PATH before drjit loads)
import pytest  # noqa: E402


@pytest.fixture(autouse=True)
def _doctests_keep_the_mitsuba_variant(request):
    """A doctest may call ``mi.set_variant`` as a user would; the tests after it
    in the same process get their variant back."""
    if not isinstance(request.node, pytest.DoctestItem):
        yield
        return
    import mitsuba as mi
    before = mi.variant()
    yield
    if before is not None and mi.variant() != before:
        mi.set_variant(before)
