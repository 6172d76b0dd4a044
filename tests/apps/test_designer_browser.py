"""The designer's page in a real headless browser (Debian's chromium, driven by
Selenium through chromium-driver; `make chromium` installs both): it loads,
builds its controls from the parameter specification, and moving the radius
slider changes the corona picture, with no console error."""
from __future__ import annotations

import os
import shutil

import pytest

pytestmark = [pytest.mark.slow, pytest.mark.browser]

pytest.importorskip("starlette")
pytest.importorskip("selenium")

pytestmark = [pytest.mark.slow, pytest.mark.browser]

CHROMIUM = os.environ.get("CORONA_CHROMIUM", "/usr/bin/chromium")
DRIVER = os.environ.get("CORONA_CHROMEDRIVER", "/usr/bin/chromedriver")

if not (os.path.exists(CHROMIUM) or shutil.which("chromium")) or not os.path.exists(DRIVER):
    if os.environ.get("CI"):
        raise RuntimeError("chromium / chromedriver missing in CI: `make chromium` (scripts/ensure_chromium.sh) "
                           "should have installed them")
    pytest.skip("Debian's chromium and chromium-driver are not installed (make chromium)", allow_module_level=True)


def test_moving_a_slider_changes_the_corona_without_console_errors():
    from designer_screenshot import chrome, picture_ready, wait_for
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    from corona.apps.designer import running
    with running() as url:
        driver = chrome(1400, 900)
        try:
            driver.get(url)
            wait_for(driver, picture_ready("a"), timeout=60, what="the first corona picture")
            # the controls come from the specification: one per material parameter
            from corona.parameters import PARAMETERS
            for p in PARAMETERS:
                if not p.plugin_only:
                    assert driver.find_elements(By.ID, "ctl-" + p.name), p.name
            img = driver.find_element(By.ID, "corona-a")
            before = (img.get_attribute("data-digest"), int(img.get_attribute("data-version")))
            radius = driver.find_element(By.ID, "num-radius").get_attribute("value")
            assert radius == "5"                                     # the "fogged window" preset
            assert img.get_attribute("naturalWidth") == "256"

            slider = driver.find_element(By.ID, "slider-radius")
            ActionChains(driver).move_to_element_with_offset(slider, slider.size["width"] // 3, 0).click().perform()
            wait_for(driver, picture_ready("a", before[1]), timeout=60, what="the corona after moving the slider")
            after = img.get_attribute("data-digest")
            new_radius = float(driver.find_element(By.ID, "num-radius").get_attribute("value"))
            assert new_radius > 5.0                                  # moved to the right: larger droplets
            assert after and after != before[0]                      # another picture
            wait_for(driver, "const e = document.getElementById('energy-legend-a'); "
                             "return e && e.textContent.includes('coherent');", timeout=60, what="the energy split")
            assert driver.find_element(By.ID, "error").get_attribute("hidden") is not None
            logs = driver.get_log("browser")
        finally:
            driver.quit()
    errors = [e["message"] for e in logs if e.get("level") == "SEVERE"]
    assert errors == []


def _set(driver, name, value, kind="sel"):
    """Set a control as a person would (its value, then its change event)."""
    driver.execute_script(f"""
        const e = document.getElementById('{kind}-{name}'); e.value = arguments[0];
        e.dispatchEvent(new Event('change'));""", value)


def test_page_follows_the_spec_keeps_the_look_in_the_url_and_shows_progress(monkeypatch):
    """Issue 43 item 5 and issue 44 item 2, in the browser at 1400 × 900:
    the page's relevance is Parameter.applies_to for every shape × process × spread × substrate it
    offers (a mixture can be rotated); inactive knobs are dimmed; an edit turns the preset to
    "custom"; the look is in the address and loading it restores the look; A and B stand side by
    side and "stop comparing" hides B's energy row; the kernel's share is shown; while a table
    builds the page shows the server's progress (a slow build stands in for a new sphere radius)."""
    import itertools
    import threading
    import io

    from designer_screenshot import chrome, picture_ready, wait_for
    from selenium.webdriver.common.by import By
    from tqdm import tqdm

    from corona.apps.designer import compute, running
    from corona.parameters import DEFAULTS, PARAMETERS, PROCESSES, SHAPES, SPEC, SUBSTRATES

    with running() as url:
        driver = chrome(1400, 900)
        try:
            driver.get(url)
            wait_for(driver, picture_ready("a"), timeout=60, what="the first corona picture")
            # -- relevance: the page's rule is the specification's, for every combination it offers
            # every knob the conditions read, at each of its choices (a threshold: below and above)
            axes = {}
            for p in PARAMETERS:
                for cond in p.applies:
                    name, sep, value = cond.partition(">") if ">" in cond else cond.partition("=")
                    axes[name] = (list(SPEC[name].choices) if SPEC[name].kind == "choice"
                                  else ["0", str(float(value) + 0.2), "abc"])
            assert {"shape", "process", "size_spread", "substrate"} <= set(axes)
            assert set(axes["shape"]) == set(SHAPES) and set(axes["process"]) == set(PROCESSES)
            assert set(axes["substrate"]) == set(SUBSTRATES)
            combos = [dict(zip(axes, values)) for values in itertools.product(*axes.values())]
            page = driver.execute_script("""
                const c = window.corona, base = {...c.state.values};
                return arguments[0].map((v) => c.relevantNames({...base, ...v}));""", combos)
            names = [p.name for p in PARAMETERS if not p.plugin_only]
            base = {**DEFAULTS, **{k: v for k, v in driver.execute_script(
                "return window.corona.state.values").items() if k in DEFAULTS and SPEC[k].kind == "choice"}}
            for combo, got in zip(combos, page):
                params = {**base, **combo}
                expected = {n: SPEC[n].applies_to(params) for n in names}
                assert {n: got[n] for n in names} == expected, combo
            # a mixture can be rotated: angle is active (and sent), aspect and sides too
            _set(driver, "mixture", "circle:2:0.5, square:1.5:0.5", kind="txt")
            _set(driver, "shape", "mixture")
            for name in ("angle", "aspect", "sides"):
                assert "inactive" not in driver.find_element(By.ID, "ctl-" + name).get_attribute("class"), name
            assert "inactive" in driver.find_element(By.ID, "ctl-radius").get_attribute("class")
            _set(driver, "shape", "circle")
            assert "inactive" in driver.find_element(By.ID, "ctl-angle").get_attribute("class")
            assert driver.find_element(By.ID, "ctl-angle").is_displayed()          # dimmed, not hidden
            assert driver.find_element(By.ID, "preset").get_attribute("value") == "custom"

            # -- the look in the address: an edit lands there, and a fresh page restores it
            n = int(driver.find_element(By.ID, "corona-a").get_attribute("data-version"))
            _set(driver, "radius", "7.5", kind="num")
            wait_for(driver, picture_ready("a", n), timeout=60, what="the picture after the edit")
            wait_for(driver, "return location.search.includes('radius=7.5');", timeout=10, what="the address")
            look = driver.current_url
            driver.get(look)
            wait_for(driver, picture_ready("a"), timeout=60, what="the picture of the shared look")
            assert driver.find_element(By.ID, "num-radius").get_attribute("value") == "7.5"
            assert driver.find_element(By.ID, "num-area_fraction").get_attribute("value") == "0.4"
            assert driver.find_element(By.ID, "preset").get_attribute("value") == "custom"
            driver.get(url)                                                        # no look: the first preset
            wait_for(driver, picture_ready("a"), timeout=60, what="the first picture again")
            assert driver.find_element(By.ID, "preset").get_attribute("value") == "fogged window"

            # -- the kernel's share of the lobe is shown (sized from the lobe: no warning)
            wait_for(driver, "return document.getElementById('kernel-info').dataset.share !== undefined;",
                     timeout=60, what="the kernel's share")
            assert float(driver.find_element(By.ID, "kernel-info").get_attribute("data-share")) >= 0.99
            assert "holds" in driver.find_element(By.ID, "kernel-info").text
            assert not driver.find_element(By.ID, "kernel-warning").is_displayed()

            # -- compare: side by side at 1400 px; "stop comparing" hides B and its energy row
            driver.find_element(By.ID, "pin").click()
            wait_for(driver, picture_ready("b"), timeout=60, what="picture B")
            a = driver.find_element(By.ID, "corona-a").rect
            b = driver.find_element(By.ID, "corona-b").rect
            assert abs(a["y"] - b["y"]) < 1 and b["x"] >= a["x"] + a["width"], (a, b)
            wait_for(driver, "return document.getElementById('energy-legend-b') !== null;", timeout=60,
                     what="B's energy split")
            assert driver.find_element(By.ID, "energy-b").is_displayed()
            driver.find_element(By.ID, "unpin").click()
            assert not driver.find_element(By.ID, "energy-b").is_displayed()
            assert not driver.find_element(By.ID, "fig-b").is_displayed()

            # -- progress while a table builds: the server's bar reaches the page
            go = threading.Event()
            real = compute.corona_png

            def slow(*args):
                with tqdm(total=40, unit="row", desc="corona: building the Mie sphere table", leave=False,
                          file=io.StringIO()) as bar:
                    for _ in range(40):
                        go.wait(0.1)
                        bar.update(1)
                return real(*args)
            monkeypatch.setattr(compute, "corona_png", slow)
            _set(driver, "radius", "6.5", kind="num")
            text = wait_for(driver, "const b = document.getElementById('busy'); "
                                    "return !b.hidden && document.getElementById('busy-text').textContent;",
                            timeout=30, what="the busy indicator")
            assert "building the Mie sphere table" in text and "/ 40 row" in text, text
            wait_for(driver, "return document.getElementById('busy').hidden;", timeout=60, what="the end of the build")
            monkeypatch.setattr(compute, "corona_png", real)
            logs = driver.get_log("browser")
        finally:
            driver.quit()
    errors = [e["message"] for e in logs if e.get("level") == "SEVERE"]
    assert errors == []


def test_a_new_sphere_radius_shows_a_preview_then_the_exact_picture():
    """Issue 43 item 6 in the browser: a look of spheres of a radius without a table (from the
    address) shows the preview at once, captioned so, with the build's progress; the exact picture
    replaces it when the table is built, without a console error."""
    from designer_screenshot import chrome, wait_for

    from corona.apps.designer import running
    with running() as url:
        driver = chrome(1400, 900)
        try:
            driver.get(url + "?shape=sphere&radius=7.3&area_fraction=0.2&process=poisson")
            wait_for(driver, "return document.getElementById('corona-a').dataset.building === '1';",
                     timeout=60, what="the preview")
            assert "coarse Mie table" in driver.execute_script("return document.getElementById('cap-a').textContent;")
            wait_for(driver, "const b = document.getElementById('busy'); return !b.hidden && "
                             "document.getElementById('busy-text').textContent.includes('7.3');",
                     timeout=60, what="the build's progress")
            wait_for(driver, "const i = document.getElementById('corona-a'); return i.dataset.building === '0' "
                             "&& i.dataset.preview === '0';", timeout=600, what="the exact picture")
            assert "preview" not in driver.execute_script("return document.getElementById('cap-a').textContent;")
            logs = driver.get_log("browser")
        finally:
            driver.quit()
    errors = [e["message"] for e in logs if e.get("level") == "SEVERE"]
    assert errors == []
