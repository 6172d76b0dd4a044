"""The tests' table cache: one folder per fingerprint of the code that builds tables, outside the clone.

Tables are keyed by their parameters (``corona.model.tabulated.cache_key``), not by the code
that builds them, so a cache kept between test runs could serve a table built by older code.
The tests therefore keep theirs in ``<root>/<fingerprint>/``, where

* ``root`` is ``$CORONA_TEST_CACHE`` or the user's cache folder for ``corona-tests``
  (``platformdirs.user_cache_dir("corona-tests")``, e.g. ``~/.cache/corona-tests``): outside the
  clone, so a fresh clone of the same code finds its tables, and never the user's own corona
  cache (``user_cache_dir("corona")``, what ``corona tables clear`` empties);
* ``fingerprint`` is a sha256 of every file of ``src/corona`` that can take part in building a
  table (its path and bytes: the physics under ``model/``, the plugin's tables under ``mitsuba/``,
  ``tables/``, ``parameters.py``, ``color.py``, the shipped ``data/*.npz``, ...), and of the
  versions of Python and the numeric libraries.  Excluded are ``apps/`` (CLI, designer, fit,
  sweep: they call the model, they build no table of their own) and ``reference/`` (the
  brute-force tier, above the model: the model never imports it; test_import_graph.py holds
  that).  Files, not bytecode: a change of a comment also starts a new folder (one cold run),
  which is the price of never reading a stale table; a byte-level hash needs no import.

Numba's compiled kernels (the reference tier) go to ``<root>/numba``: numba keys them itself
on the source file's path and modification time.

Pruning (``prune``, run by ../conftest.py at each test session): a fingerprint folder holds
some hundreds of MB, and every edit of the table-building code starts one, so the root keeps the
``KEEP_COUNT`` most recently used folders (their ``.last-used`` stamps) and deletes any other,
and any folder unused for ``KEEP_DAYS`` whatever the count; a folder used within ``BUSY_HOURS``
is never deleted by the count (another checkout's run may be writing to it).

``python scripts/suite_cache.py path|root|clear|prune`` prints the folder, the root, deletes
every test cache (``make clean-cache``), or prunes it as above.
"""
from __future__ import annotations

import hashlib
import os
import shutil
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
SRC = os.path.join(HERE, os.pardir, "src", "corona")
#: sub-folders of src/corona that build no table (see the module docstring)
EXCLUDED = ("apps", "reference")
#: the libraries whose versions are part of the fingerprint (a numeric change is a new folder)
LIBRARIES = ("numpy", "scipy", "numba", "mitsuba", "drjit")
#: a fingerprint folder unused this long is deleted by ``prune`` (run at each test session)
KEEP_DAYS = 14
#: ``prune`` keeps at most this many fingerprint folders (the most recently used), beyond
#: those in use (:data:`BUSY_HOURS`): a few checkouts or branches of the code, each warm
KEEP_COUNT = 4
#: a folder used this recently is never deleted by the count: a run may still be writing to it
BUSY_HOURS = 2.0
STAMP = ".last-used"


def _versions() -> str:
    from importlib import metadata
    out = [sys.version]
    for name in LIBRARIES:
        try:
            out.append(f"{name}={metadata.version(name)}")
        except metadata.PackageNotFoundError:
            out.append(f"{name}=absent")
    return "\n".join(out)


def fingerprint(src: str = SRC, versions: str | None = None) -> str:
    """sha256 (24 hex digits) of the table-building files under ``src`` and the library versions."""
    src = os.path.abspath(src)
    h = hashlib.sha256()
    h.update((_versions() if versions is None else versions).encode())
    files = []
    for folder, dirs, names in os.walk(src):
        rel = os.path.relpath(folder, src)
        dirs[:] = sorted(d for d in dirs if d != "__pycache__"
                         and not (rel == "." and d in EXCLUDED))
        files += [os.path.join(folder, n) for n in names if not n.endswith((".pyc", ".pyo"))]
    for path in sorted(files):
        h.update(b"\0" + os.path.relpath(path, src).replace(os.sep, "/").encode() + b"\0")
        with open(path, "rb") as f:
            h.update(f.read())
    return h.hexdigest()[:24]


def root() -> str:
    """``$CORONA_TEST_CACHE`` or the user's cache folder for corona's tests."""
    path = os.environ.get("CORONA_TEST_CACHE")
    if not path:
        import platformdirs
        path = platformdirs.user_cache_dir("corona-tests")
    return os.path.abspath(path)


def folder(src: str = SRC) -> str:
    """The table cache of the tests of this source tree (created, its last use stamped)."""
    path = os.path.join(root(), fingerprint(src))
    os.makedirs(path, exist_ok=True)
    with open(os.path.join(path, STAMP), "w") as f:
        f.write(f"{time.time():.0f}\n")
    return path


def prune(keep_days: float = KEEP_DAYS, keep_count: int = KEEP_COUNT,
          busy_hours: float = BUSY_HOURS) -> list[str]:
    """Delete the fingerprint folders of ``root()`` not used for ``keep_days`` (their stamp's age),
    and the least recently used beyond the newest ``keep_count``, except those used within
    ``busy_hours``.  Returns the deleted paths."""
    base, gone = root(), []
    if not os.path.isdir(base):
        return gone
    now = time.time()
    stamped = []
    for name in os.listdir(base):
        stamp = os.path.join(base, name, STAMP)
        if name == "numba":
            continue
        try:
            stamped.append((os.path.getmtime(stamp), os.path.join(base, name)))
        except OSError:     # no stamp (not a fingerprint folder, or being made): left alone
            continue
    stamped.sort(reverse=True)
    for rank, (used, path) in enumerate(stamped):
        expired = used < now - keep_days * 86400
        surplus = rank >= keep_count and used < now - busy_hours * 3600
        if expired or surplus:
            shutil.rmtree(path, ignore_errors=True)
            gone.append(path)
    return gone


def clear() -> str:
    """Delete every test cache (all fingerprints and numba's kernels)."""
    base = root()
    shutil.rmtree(base, ignore_errors=True)
    return base


def main(argv: list[str]) -> int:
    cmd = argv[0] if argv else "path"
    if cmd == "path":
        print(folder())
    elif cmd == "root":
        print(root())
    elif cmd == "clear":
        print(f"removed {clear()}")
    elif cmd == "prune":
        for path in prune():
            print(f"removed {path}")
    else:
        print("usage: python scripts/suite_cache.py [path|root|clear|prune]", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
