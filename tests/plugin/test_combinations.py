"""Every scatterer family × every layer feature, rendered: the matrix in docs/combinations.md.

Each cell loads a ``corona`` layer of one shape family with one feature on
a pane in front of a lamp and renders it (12×12 pixels, 4 samples per
pixel, ``path``).  A cell either renders a finite image (✓; with the
"unused parameter" warning where the feature means nothing for that shape),
or is refused at load with one line, a ``CoronaError`` naming the parameter
(✗, the line in the notes).  Anything else (another exception, a NaN or an
infinity in the image) fails the test.  The Markdown table the test builds
must equal docs/combinations.md; regenerate it with

    PYTHONPATH=src python tests/plugin/test_combinations.py
"""
import os
import sys
import warnings

import numpy as np
import pytest

pytestmark = [pytest.mark.slow, pytest.mark.render]

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), os.pardir, os.pardir)
DOC = os.path.join(ROOT, "docs", "combinations.md")

#: the shape families, each a small scatterer (cheap tables) at F_a = 0.2, hard-disk
FAMILIES = {
    "circle": {"radius": 1.5},
    "ellipse": {"shape": "ellipse", "radius": 1.5, "aspect": 0.6, "angle": 20.0},
    "square": {"shape": "square", "radius": 1.2},
    "polygon": {"shape": "polygon", "sides": 6, "radius": 1.5},
    "mixture": {"shape": "mixture", "mixture": "circle:1.5:0.5, square:1.2:0.5"},
    "sphere": {"shape": "sphere", "radius": 2.0},
}
LARGEST = {"circle": 1.5, "ellipse": 1.5, "square": 1.2, "polygon": 1.5, "mixture": 1.5, "sphere": 2.0}


def _bitmap(values):
    import mitsuba as mi
    return {"type": "bitmap", "bitmap": mi.Bitmap(np.asarray(values, np.float32)[..., None]),
            "raw": True, "filter_type": "nearest"}


#: the sphere's radius texture is drawn with a constant index: with water's dispersion one table holds
#: one radius's index, and a range wider than its span is refused (docs/layer.md#sphere-radius-textures)
CONSTANT_INDEX = {"sphere": {"ior": 1.333}}


def _features(family):
    r = LARGEST[family]
    return {
        "F_a texture": {"area_fraction": _bitmap([[0.05, 0.12], [0.17, 0.2]])},
        "radius texture": {"radius": _bitmap([[0.6 * r, r], [0.8 * r, r]]), **CONSTANT_INDEX.get(family, {})},
        "albedo texture": {"albedo": _bitmap([[0.1, 0.4], [0.6, 0.3]])},
        "glass": {"substrate": "glass"},
        "size spread": {"size_spread": 0.1},
        "random orientation": {"orientation": "random"},
        "soft edge": {"edge_width": 0.1},
        "rsa": {"process": "rsa"},
        "lattice": {"process": "lattice-hex"},
    }


FEATURES = list(_features("circle"))


def _scene(bsdf):
    import mitsuba as mi
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "path", "max_depth": 3},
        "sensor": {"type": "perspective", "fov": 30,
                   "to_world": mi.ScalarTransform4f().look_at([0, 0, 4], [0, 0, 0], [0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 12, "height": 12, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": 4}},
        "pane": {"type": "rectangle", "bsdf": bsdf},
        "lamp": {"type": "sphere", "radius": 0.3, "center": [0, 0, -3],
                 "emitter": {"type": "area", "radiance": {"type": "uniform", "value": 20.0}}},
        "sky": {"type": "constant", "radiance": {"type": "uniform", "value": 0.1}},
    })


def _refusal(err) -> str | None:
    """The CoronaError line of a load error (Mitsuba wraps the plugin's exception), else None."""
    from corona import CoronaError
    if isinstance(err, CoronaError):
        return str(err)
    lines = [ln for ln in str(err).splitlines() if ln.startswith("CoronaError: ")]
    return lines[-1][len("CoronaError: "):] if lines else None


def cell(family, feature):
    """("ok" | "unused" | "refused", detail) of one cell; raises on anything else."""
    import mitsuba as mi
    from corona import CoronaWarning
    bsdf = {"type": "corona", "process": "hard-disk", "area_fraction": 0.2, **FAMILIES[family],
            **_features(family)[feature]}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", CoronaWarning)
        try:
            scene = _scene(bsdf)
        except Exception as err:      # noqa: BLE001 - classified below
            line = _refusal(err)
            if line is None:
                raise AssertionError(f"{family} × {feature}: not a CoronaError: {err}") from err
            assert "\n" not in line, (family, feature, line)
            return "refused", line
    img = np.asarray(mi.render(scene, seed=0))
    assert np.all(np.isfinite(img)), (family, feature)
    unused = [str(w.message) for w in caught if "unused parameter" in str(w.message)]
    return ("unused", unused[0]) if unused else ("ok", "")


def matrix() -> str:
    """docs/combinations.md: the table of every cell and the notes of its refusals."""
    notes: list[str] = []
    rows = []
    for family in FAMILIES:
        cells = []
        for feature in FEATURES:
            kind, detail = cell(family, feature)
            if kind == "ok":
                cells.append("✓")
            elif kind == "unused":
                cells.append("✓ (unused)")
            else:
                if detail not in notes:
                    notes.append(detail)
                cells.append(f"✗ [{notes.index(detail) + 1}]")
        rows.append(f"| {family} | " + " | ".join(cells) + " |")
    ok = sum(r.count("✓") for r in rows)
    lines = [
        "# Every scatterer family × every layer feature",
        "",
        "Generated by `tests/plugin/test_combinations.py` (which checks this file): each cell is a "
        "`corona` layer of that shape with that feature (hard-disk positions, F_a = 0.2, "
        "µm-sized scatterers), rendered at 12×12 pixels, 4 spp. ✓: a finite image; "
        "✓ (unused): the feature means nothing for that shape, which the plugin says in its "
        "one \"unused parameter\" warning, and the layer renders without it; "
        "✗: refused at load with the one line in the notes.",
        "",
        "The sphere's radius texture is drawn with a constant index (ior = 1.333): with water's "
        "dispersion the rows of one table hold the index of one radius, and a texture wider than the "
        "span that allows (a factor 1.02 about 2 µm) is refused in one line "
        "(docs/layer.md#sphere-radius-textures).",
        "",
        "| shape | " + " | ".join(FEATURES) + " |",
        "|---|" + "---|" * len(FEATURES),
        *rows,
        "",
        f"{ok} of {len(FAMILIES) * len(FEATURES)} cells render.",
        "",
    ]
    if notes:
        lines += ["Refusals:", ""] + [f"{i + 1}. {n}" for i, n in enumerate(notes)] + [""]
    return "\n".join(lines)


def test_every_cell_renders_or_is_refused_in_one_line_as_documented(mi_variant):
    text = matrix()
    with open(DOC, encoding="utf-8") as f:
        assert f.read() == text, ("docs/combinations.md drifted: regenerate it with "
                                  "`PYTHONPATH=src python tests/plugin/test_combinations.py`")


if __name__ == "__main__":
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import corona
    import mitsuba as mi
    mi.set_variant(corona.default_variant(prefer_gpu=False))
    corona.register()
    with open(DOC, "w", encoding="utf-8") as f:
        f.write(matrix())
    print(f"wrote {os.path.normpath(DOC)}")
