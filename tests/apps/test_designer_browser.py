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
