#!/usr/bin/env bash
# Make sure Debian's headless Chromium and its matching chromedriver are
# installed, for the browser test of `corona designer` (tests/apps/test_designer_browser.py).
# Idempotent: does nothing when both are present. Never downloads a browser build
# of its own: only the distribution's packages.
set -u
if command -v chromium >/dev/null 2>&1 && command -v chromedriver >/dev/null 2>&1; then
  exit 0
fi
if command -v apt-get >/dev/null 2>&1; then
  SUDO=""; [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1 && SUDO="sudo -n"
  echo "corona: installing chromium and chromium-driver for the designer's browser test" >&2
  ($SUDO apt-get update -qq && $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
      --no-install-recommends chromium chromium-driver) >/dev/null 2>&1 \
    || echo "corona: could not install chromium; the designer's browser test will be skipped" >&2
else
  echo "corona: no chromium and no apt-get; the designer's browser test will be skipped" >&2
fi
exit 0
