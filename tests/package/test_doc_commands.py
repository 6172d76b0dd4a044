"""Every documented command runs: the README's, the docs pages' and the scene headers'.

What is collected (:func:`collect`):

* every fenced ```` ```sh ```` and ```` ```python ```` block of ``README.md`` and
  ``docs/**/*.md`` (``docs/_build`` left out);
* the ``corona ...`` lines of each scene file's header comment (``scenes/*.xml``), without
  their trailing ``(explanation)``.

How it runs (:func:`run_case`): each case in a fresh temporary folder holding a copy of
``scenes/`` and ``examples/`` (what a checkout gives a newcomer), with ``corona`` and
``python`` on ``PATH`` meaning the interpreter under test; every command line is its own
process (``bash -c``), in order, so a block's later commands see what its earlier ones
wrote.  A page's Python blocks run in order as one script, as a reader would paste them.
Renders are scaled down: ``corona render`` and ``corona sweep`` get ``-D res=64`` (an
existing ``-D res=...`` replaced) and ``--spp 4``.  A scene header's command that a page
already runs (the same command once ``--out``, ``--name`` and ``--exposure`` are taken
off: the gallery's commands are the scene headers' with an output name) is not run twice, and a
``corona render``/``sweep``/``lobe`` command that an earlier case of this process ran on the same
files (the same command line, every file of the folder the same bytes) is not run again: its
outputs are copied into the folder (the renders are seeded, so a second run writes the same bytes).

A block that cannot run here says why in a marker on the line right above its fence::

    <!-- doc-commands: skip: a web server that runs until Ctrl-C -->

and ``<!-- doc-commands: skip-page: REASON -->`` anywhere on a page skips all its blocks
(the tutorial: its blocks are ``examples/tutorial.py``, which test_docs.py runs).  The
skipped cases are reported by pytest with their reasons; keep them few.
"""
from __future__ import annotations

import dataclasses
import glob
import os
import re
import shlex
import shutil
import subprocess
import sys

import pytest

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir, os.pardir))
#: what the commands may read from the checkout: copied into each case's folder
COPIED = ("scenes", "examples")
#: the scaled-down renders
RES, SPP = 64, 4
#: per command (a cold Mie table is tens of seconds on two cores)
TIMEOUT = 900

_FENCE = re.compile(r"^\s*(`{3,}|~{3,})\s*([^\s`{]*)")
#: a scene header's command line (not prose that starts with the word corona)
_COMMAND = re.compile(r"corona (render|sweep|lobe|fit|post|designer|tables|doctor|validate)\b")
_MARKER = re.compile(r"<!--\s*doc-commands:\s*(skip|skip-page):\s*(.*?)\s*-->")


@dataclasses.dataclass
class Case:
    """One thing to run: the shell lines of a block or a scene header, or a page's Python."""
    source: str                 # path relative to the checkout
    line: int                   # first line (1-based) of the first block
    lang: str                   # "sh" or "python"
    code: str                   # sh: one command per line (continuations joined); python: the script
    skip: str | None = None     # the reason, when it is not run

    @property
    def id(self) -> str:
        return f"{self.source}:{self.line}:{self.lang}"

    def commands(self) -> list[str]:
        """The shell lines that are commands (comments and blank lines left out)."""
        return [c for c in self.code.splitlines() if c.strip() and not c.lstrip().startswith("#")]


def markdown_blocks(text: str, source: str) -> list[Case]:
    """The ``sh``/``python`` fenced blocks of a Markdown page, each with the reason of the
    marker right above its fence (blank lines between allowed), if any.

    >>> page = "a\\n<!-- doc-commands: skip: a server -->\\n```sh\\ncorona designer\\n```\\n" \\
    ...        "````text\\n```sh\\nnot a block\\n```\\n````\\n```python\\nprint(1)\\n```\\n"
    >>> [(c.lang, c.code, c.skip) for c in markdown_blocks(page, "p.md")]
    [('sh', 'corona designer', 'a server'), ('python', 'print(1)', None)]
    """
    page_skip = None
    lines = text.splitlines()
    cases: list[Case] = []
    fence = None                # the opening fence while inside a block
    lang = body = start = reason = None
    last = ""                   # the last non-blank line outside blocks
    for i, line in enumerate(lines, 1):
        if fence is None:
            m = _FENCE.match(line)
            if m:
                fence, lang, body, start = m.group(1), m.group(2).lower(), [], i
                marker = _MARKER.search(last)
                reason = marker.group(2) if marker and marker.group(1) == "skip" else None
                continue
            marker = _MARKER.search(line)
            if marker and marker.group(1) == "skip-page":
                page_skip = marker.group(2)
            if line.strip():
                last = line
        elif line.strip().startswith(fence) and not line.strip().strip(fence[0]):
            if lang in ("sh", "python"):
                cases.append(Case(source, start, lang, "\n".join(body), reason))
            fence, last = None, ""
        else:
            body.append(line)
    for c in cases:
        if page_skip and c.skip is None:
            c.skip = page_skip
        if c.lang == "sh":
            c.code = c.code.replace("\\\n", " ")
    return cases


def scene_commands(text: str, source: str) -> Case | None:
    """The ``corona ...`` lines of a scene file's first comment, without their
    ``(explanation)``.

    >>> scene_commands("<?xml?>\\n<!--\\n  a scene\\n  corona render scenes/a.xml   (10x)\\n-->\\n<scene/>", "a.xml").code
    'corona render scenes/a.xml'
    """
    m = re.search(r"<!--(.*?)-->", text, re.S)
    if not m:
        return None
    first = text[:m.start()].count("\n") + 1
    lines = []
    for k, line in enumerate(m.group(1).splitlines()):
        stripped = line.strip()
        if _COMMAND.match(stripped):
            lines.append((first + k, re.split(r"\s+\(", stripped)[0].rstrip()))
    if not lines:
        return None
    return Case(source, lines[0][0], "sh", "\n".join(c for _, c in lines))


def scaled(command: str) -> str:
    """A ``corona render``/``corona sweep`` command at ``RES`` pixels and ``SPP`` samples.

    >>> scaled("corona render scenes/t.xml -D res=256 -D spp=64 --out o")
    'corona render scenes/t.xml -D res=64 -D spp=64 --out o --spp 4'
    >>> scaled("corona sweep s.xml -D radius=1,2  # two points")
    'corona sweep s.xml -D radius=1,2 -D res=64 --spp 4'
    >>> scaled("corona lobe --radius 5")
    'corona lobe --radius 5'
    """
    words = shlex.split(command, comments=True)
    if len(words) < 2 or words[0] != "corona" or words[1] not in ("render", "sweep"):
        return command
    out, k = [], 0
    while k < len(words):
        w = words[k]
        if w == "--spp":
            k += 2
            continue
        if w == "-D" and k + 1 < len(words) and words[k + 1].startswith("res="):
            words[k + 1] = f"res={RES}"
        out.append(w)
        k += 1
    if f"res={RES}" not in out:
        out += ["-D", f"res={RES}"]
    return shlex.join(out + ["--spp", str(SPP)])


def _normalised(command: str) -> str:
    """A command without its output options (to find the same render run twice)."""
    words = shlex.split(scaled(command), comments=True)
    out, k = [], 0
    while k < len(words):
        if words[k] in ("--out", "--name", "--exposure"):
            k += 2
            continue
        out.append(words[k])
        k += 1
    return " ".join(out)


def collect() -> list[Case]:
    """Every case: the pages' blocks (a page's Python blocks merged into one script, in
    order) and the scene headers' commands that no page runs already."""
    pages = ["README.md"] + sorted(
        os.path.relpath(p, ROOT) for p in glob.glob(os.path.join(ROOT, "docs", "**", "*.md"), recursive=True)
        if os.sep + "_build" + os.sep not in p)
    cases: list[Case] = []
    for page in pages:
        blocks = markdown_blocks(open(os.path.join(ROOT, page), encoding="utf-8").read(), page)
        cases += [b for b in blocks if b.lang == "sh"]
        for run in (True, False):           # the page's script; its skipped blocks, as one case
            python = [b for b in blocks if b.lang == "python" and (b.skip is None) == run]
            if python:
                cases.append(Case(page, python[0].line, "python", "\n\n".join(b.code for b in python),
                                  None if run else "; ".join(sorted({b.skip for b in python}))))
    ran = {_normalised(c) for case in cases if case.lang == "sh" and case.skip is None for c in case.commands()}
    for scene in sorted(glob.glob(os.path.join(ROOT, "scenes", "*.xml"))):
        case = scene_commands(open(scene, encoding="utf-8").read(), os.path.relpath(scene, ROOT))
        if case is None:
            continue
        fresh = [c for c in case.commands() if _normalised(c) not in ran]
        if fresh:
            case.code = "\n".join(fresh)
            cases.append(case)
    return cases


CASES = collect()


def _shims(folder: str) -> str:
    """``corona`` and ``python`` meaning the interpreter (and the corona) under test."""
    os.makedirs(folder, exist_ok=True)
    for name, target in (("corona", f'"{sys.executable}" -m corona.apps.cli'),
                         ("python", f'"{sys.executable}"'), ("python3", f'"{sys.executable}"')):
        path = os.path.join(folder, name)
        with open(path, "w") as f:
            f.write(f'#!/bin/sh\nexec {target} "$@"\n')
        os.chmod(path, 0o755)
    return folder


#: the renders, sweeps and lobe pictures run in this process: (the command's words, :func:`_state` of
#: the folder it ran in) → the files it wrote there ({relative path: bytes}); a later case running the
#: very same command on the very same files (the pages repeat a few: the moon photograph of `corona
#: fit`, a sweep, a lobe picture) gets those files instead of a second identical process (seeded
#: renders, deterministic pictures: the same bytes)
_DONE: dict[tuple, dict[str, bytes]] = {}


def _state(folder) -> dict[str, bytes]:
    """Every file under ``folder``: {relative path: sha256 of its bytes}."""
    import hashlib
    out = {}
    for d, _, names in os.walk(folder):
        for n in names:
            path = os.path.join(d, n)
            with open(path, "rb") as f:
                out[os.path.relpath(path, folder)] = hashlib.sha256(f.read()).digest()
    return out


def _reusable(command: str) -> bool:
    words = shlex.split(command, comments=True)
    return len(words) > 1 and words[0] == "corona" and words[1] in ("render", "sweep", "lobe")


def run_case(case: Case, tmp_path, cache: str) -> None:
    import corona
    work = tmp_path / "work"
    work.mkdir()
    for name in COPIED:
        shutil.copytree(os.path.join(ROOT, name), work / name, ignore=shutil.ignore_patterns("__pycache__"))
    package_root = os.path.dirname(os.path.dirname(os.path.abspath(corona.__file__)))
    env = {**os.environ,
           "PATH": _shims(str(tmp_path / "bin")) + os.pathsep + os.environ.get("PATH", ""),
           "PYTHONPATH": os.pathsep.join(p for p in (package_root, os.environ.get("PYTHONPATH")) if p),
           "CORONA_CACHE_DIR": cache, "MPLBACKEND": "Agg"}
    if case.lang == "python":
        script = work / "doc_snippet.py"
        script.write_text(case.code + "\n", encoding="utf-8")
        runs = [(f"{case.source}'s Python blocks", [sys.executable, str(script)])]
    else:
        runs = [(scaled(c), ["bash", "-c", scaled(c)]) for c in case.commands()]
    for shown, argv in runs:
        before = _state(work) if case.lang == "sh" and _reusable(shown) else None
        key = (tuple(shlex.split(shown, comments=True)), tuple(sorted(before.items()))) if before is not None else None
        if key in _DONE:                        # run already, on the same files: its outputs
            for rel, data in _DONE[key].items():
                os.makedirs(os.path.dirname(work / rel), exist_ok=True)
                (work / rel).write_bytes(data)
            continue
        r = subprocess.run(argv, cwd=work, env=env, capture_output=True, text=True, timeout=TIMEOUT)
        report = f"{case.id}: `{shown}` exited with {r.returncode}\n{r.stderr[-3000:]}"
        assert r.returncode == 0, report
        assert "Traceback (most recent call last)" not in r.stderr, report
        if key is not None:
            after = _state(work)
            _DONE[key] = {rel: (work / rel).read_bytes() for rel, h in after.items() if before.get(rel) != h}


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """The table cache: the session's (CORONA_CACHE_DIR) or one for this module."""
    return os.environ.get("CORONA_CACHE_DIR") or str(tmp_path_factory.mktemp("doc-commands-cache"))


@pytest.mark.slow
@pytest.mark.render
@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_documented_command_runs(case, tmp_path, cache):
    if case.skip is not None:
        pytest.skip(case.skip)
    run_case(case, tmp_path, cache)


def test_the_documentation_has_commands_and_few_skips():
    """The collection finds what the pages show (a broken fence or marker would lose
    blocks silently), and every skipped block says why."""
    ids = {c.id.split(":")[0] for c in CASES}
    for page in ("README.md", "docs/cli.md", "docs/gallery.md", "docs/parameters.md"):
        assert page in ids, f"no runnable block found in {page}"
    readme = [c for c in CASES if c.source == "README.md"]
    assert any(c.lang == "python" and "corona.register()" in c.code for c in readme)
    assert any("corona fit" in c.code and c.skip is None for c in readme)
    skipped = [c for c in CASES if c.skip is not None]
    assert all(len(c.skip) >= 20 for c in skipped), [c.id for c in skipped if len(c.skip) < 20]
    assert len(skipped) <= 0.25 * len(CASES), [c.id for c in skipped]
