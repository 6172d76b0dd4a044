"""Build the docs with warnings as errors and check that they read offline.

    python scripts/check_docs.py [OUT_DIR]         (make docs-check; CI runs it)

A full build (-E) of docs/ with -W into OUT_DIR (default docs/_build/html), then:
no page refers to a CDN or any other remote script, every page with math loads
the MathJax copy under _static/mathjax, and that copy has its TeX input and its
fonts.  Exit status 1 with one line per problem.
"""
import glob
import os
import re
import subprocess
import sys

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir))


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    out = os.path.abspath(argv[0]) if argv else os.path.join(ROOT, "docs", "_build", "html")
    doctrees = os.path.join(os.path.dirname(out), "doctrees-check")
    r = subprocess.run([sys.executable, "-m", "sphinx", "-b", "html", "-q", "-E", "-W", "--keep-going",
                        "-c", os.path.join(ROOT, "docs", "api"), "-d", doctrees,
                        os.path.join(ROOT, "docs"), out])
    if r.returncode:
        print("docs: the build has warnings or errors (above)")
        return 1
    problems = []
    remote = re.compile(r"""<(?:script|link)[^>]+(?:src|href)=["'](?:https?:)?//""", re.I)
    pages = glob.glob(os.path.join(out, "**", "*.html"), recursive=True)
    with_math = 0
    for page in pages:
        text = open(page, encoding="utf-8").read()
        if remote.search(text) or re.search(r"cdn\.|jsdelivr|cdnjs|unpkg", text):
            problems.append(f"{os.path.relpath(page, out)}: refers to a remote script or stylesheet")
        if 'class="math' in text:
            with_math += 1
            if "_static/mathjax/tex-chtml.js" not in text:
                problems.append(f"{os.path.relpath(page, out)}: has math but does not load _static/mathjax")
    mj = os.path.join(out, "_static", "mathjax")
    for need in ("tex-chtml.js", "output/chtml/fonts/woff-v2", "input/tex/extensions"):
        if not os.path.exists(os.path.join(mj, need)):
            problems.append(f"_static/mathjax/{need} is missing")
    if with_math == 0:
        problems.append("no page has math: the check checked nothing")
    for p in problems:
        print("docs:", p)
    if not problems:
        print(f"docs: {len(pages)} pages in {out}, {with_math} with math typeset by the local MathJax, "
              "no remote scripts")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
