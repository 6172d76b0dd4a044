"""Screenshot of `corona designer` in headless Chromium -> docs/images/designer.png.

    python scripts/designer_screenshot.py [--out docs/images/designer.png] [--compare]

Needs the designer and test extras (make venv) and Debian's chromium and
chromium-driver (make chromium). The picture is palette-quantised to stay small.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))


def chrome(width: int = 1480, height: int = 1000):
    """Headless Debian Chromium driven by its chromedriver (no browser download), with
    the console log kept (``driver.get_log('browser')``)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    opts = webdriver.ChromeOptions()
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
              f"--window-size={width},{height}", "--hide-scrollbars", "--force-device-scale-factor=1"):
        opts.add_argument(a)
    opts.binary_location = os.environ.get("CORONA_CHROMIUM", "/usr/bin/chromium")
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    service = Service(executable_path=os.environ.get("CORONA_CHROMEDRIVER", "/usr/bin/chromedriver"))
    return webdriver.Chrome(options=opts, service=service)


def wait_for(driver, condition, timeout: float = 30.0, what: str = "the page"):
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        value = driver.execute_script(condition)
        if value:
            return value
        time.sleep(0.05)
    raise TimeoutError(f"{what} did not become ready within {timeout:g} s")


def picture_ready(side: str = "a", after: int = 0) -> str:
    """JavaScript: true once picture ``side`` has been shown more than ``after`` times."""
    return f"const i = document.getElementById('corona-{side}'); return Number(i.dataset.version) > {after} && i.complete;"


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default=os.path.join(HERE, "..", "docs", "images", "designer.png"))
    args = ap.parse_args()
    from PIL import Image

    from corona.apps.designer import running
    with running() as url:
        driver = chrome(1480, 1120)
        try:
            driver.get(url)
            wait_for(driver, picture_ready("a"), what="picture A")
            wait_for(driver, "return document.getElementById('energy-legend-a') !== null", what="the energy split")
            # compare: pin the fogged window as B, then make A the lycopodium-like larger droplets
            driver.execute_script("document.getElementById('pin').click()")
            wait_for(driver, picture_ready("b"), what="picture B")
            n = int(driver.execute_script("return document.getElementById('corona-a').dataset.version"))
            driver.execute_script("""
                const n = document.getElementById('num-radius'); n.value = '8';
                n.dispatchEvent(new Event('change'));""")
            wait_for(driver, picture_ready("a", n), what="picture A after the change")
            time.sleep(1.0)                      # profiles, energy and B follow
            path = os.path.abspath(args.out)
            os.makedirs(os.path.dirname(path), exist_ok=True)
            driver.save_screenshot(path)
            errors = [e for e in driver.get_log("browser") if e.get("level") == "SEVERE"]
        finally:
            driver.quit()
    Image.open(path).convert("RGB").quantize(colors=128, method=Image.Quantize.MEDIANCUT).save(path, optimize=True)
    print(f"{path} ({os.path.getsize(path) // 1024} KB); console errors: {len(errors)}")
    for e in errors:
        print("  ", e.get("message"))
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
