import os
import sys
import tempfile

# scripts/ (gallery, demo) need a source checkout; the tests run from one
sys.path.insert(0, os.path.join(os.path.dirname(__file__), os.pardir, "scripts"))

# Tables built by the tests go to a private cache, never the user's.
os.environ.setdefault("CORONA_CACHE_DIR", tempfile.mkdtemp(prefix="corona-test-cache-"))

import corona  # noqa: E402,F401  (sets DRJIT_LIBLLVM_PATH before drjit loads)
import pytest  # noqa: E402


@pytest.fixture(scope="session")
def mi_variant():
    """The default variant (llvm_ad_spectral here), with the plugin registered."""
    import mitsuba as mi
    variant = corona.default_variant(prefer_gpu=False)
    mi.set_variant(variant)
    corona.register()
    return variant
