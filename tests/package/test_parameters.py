"""The one parameter specification: the plugin, the CLI and docs/parameters.md agree with it."""
import os
import re

import click
import pytest

from corona import CoronaError
from corona.apps.cli import lobe
from corona.parameters import DEFAULTS, PARAMETERS, SPEC, markdown_table, material_from_parameters

ROOT = os.path.join(os.path.dirname(__file__), os.pardir, os.pardir)


def test_docs_table_is_the_specification():
    """docs/parameters.md (where the README and the docs' index send readers) carries
    the generated table, as the specification has it."""
    text = open(os.path.join(ROOT, "docs", "parameters.md"), encoding="utf-8").read()
    m = re.search(r"<!-- parameters:[^\n]*-->\n(.*?)\n<!-- /parameters -->", text, re.S)
    assert m, "docs/parameters.md lost its generated parameter table"
    assert m.group(1).strip() == markdown_table().strip(), \
        "docs/parameters.md's parameter table drifted: regenerate it with `python -m corona.parameters`"
    readme = open(os.path.join(ROOT, "README.md"), encoding="utf-8").read()
    assert "docs/parameters.md" in readme, "the README no longer links the parameter table"


def test_corona_lobe_has_every_material_parameter_with_the_spec_default():
    opts = {p.name: p for p in lobe.params if isinstance(p, click.Option)}
    for spec in PARAMETERS:
        if spec.plugin_only:
            assert spec.name not in opts
            continue
        assert spec.name in opts, f"corona lobe lacks --{spec.name.replace('_', '-')}"
        opt = opts[spec.name]
        assert opt.default == spec.default, spec.name
        if spec.kind == "choice":
            assert tuple(opt.type.choices) == spec.choices


def test_plugin_docstring_and_properties_follow_the_spec(mi_variant):
    import mitsuba as mi

    from corona.mitsuba import bsdf as mitsuba_bsdf
    for p in PARAMETERS:
        assert f"``{p.name}``" in mitsuba_bsdf.__doc__
    with pytest.raises(Exception, match="unknown parameter 'radius_um'"):
        mi.load_dict({"type": "corona", "radius_um": 1.0})
    # every choice of every choice parameter is accepted by the plugin
    for p in PARAMETERS:
        if p.kind == "choice" and p.name in ("orientation", "size_distribution", "mode", "sampling"):
            for c in p.choices:
                mi.load_dict({"type": "corona", "radius": 3.0, p.name: c,
                              **({"size_spread": 0.1} if p.name == "size_distribution" else {})})


@pytest.mark.parametrize("p", [p for p in PARAMETERS if p.kind in ("float", "int")], ids=lambda p: p.name)
def test_numeric_ranges_are_enforced_at_the_boundary(p):
    """A value just outside the documented range is rejected, naming the parameter."""
    import math
    bad = p.high * 1.5 if math.isfinite(p.high) and p.high > 0 else (
        p.low - 1.0 if math.isfinite(p.low) else math.nan)
    with pytest.raises(CoronaError, match=p.name):
        SPEC[p.name].check(bad)
    with pytest.raises(CoronaError, match=p.name):
        material_from_parameters(**{p.name: float("nan")}) if not p.plugin_only else SPEC[p.name].check(math.nan)


def test_defaults_build_the_documented_material():
    m = material_from_parameters()
    assert m.area_fraction == DEFAULTS["area_fraction"]
    assert m.mode == DEFAULTS["mode"] and m.albedo == DEFAULTS["albedo"]
    assert m.length_scale == DEFAULTS["radius"]


def test_defaults_are_the_designers_fogged_window(mi_variant):
    """One set of defaults shows a corona: the designer's opening look (water-droplet disks
    of 5 µm, hard disks, F_a 0.4, particles), for the spec, the plugin, `corona lobe` and
    `corona post`.  Coherent beam (1 - F_a)² = 0.36 (particles; apertures would give 0.16)."""
    import json

    from click.testing import CliRunner

    from corona.apps import post
    from corona.apps.cli import main
    from corona.apps.designer.compute import PRESETS
    look = PRESETS["fogged window"]["material"]
    assert {k: DEFAULTS[k] for k in look} == look
    assert look == {"shape": "circle", "radius": 5.0, "area_fraction": 0.4, "process": "hard-disk",
                    "mode": "particle"}
    m = material_from_parameters()
    assert m.coherent_transmittance == pytest.approx(0.36)
    assert repr(post.layer()) == repr(m)
    res = CliRunner().invoke(main, ["lobe", "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["coherent_transmittance"] == pytest.approx(0.36) and out["length_scale_um"] == 5.0
    # the plugin (its own parameter path, corona.mitsuba.bsdf)
    import mitsuba as mi

    import corona
    mi.set_variant(mi_variant)
    corona.register()
    bsdf = mi.load_dict({"type": "corona"})
    assert repr(m) in str(bsdf)
