"""pytest setup shared by tests/ and the doctests of src/corona (see testpaths in pyproject.toml)."""
import os
import tempfile

# Tables built by the tests and the doctests go to a private cache, never the user's.
os.environ.setdefault("CORONA_CACHE_DIR", tempfile.mkdtemp(prefix="corona-test-cache-"))

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
