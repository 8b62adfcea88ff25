"""Open a report's ``index.html`` in a real headless browser (Debian's Chromium, driven by Selenium).

Nothing is downloaded at run time: the browser is ``/usr/bin/chromium`` and the
driver ``/usr/bin/chromedriver`` (``apt-get install chromium chromium-driver``);
where either is missing, or Selenium is not installed, the calling test is
skipped with the reason.
"""

from __future__ import annotations

import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import pytest

CHROMIUM = Path("/usr/bin/chromium")
CHROMEDRIVER = Path("/usr/bin/chromedriver")
FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
)


@dataclass
class PageCheck:
    """What the browser saw: every image (src, alt, naturalWidth), the console's errors, the title."""

    title: str
    images: list[tuple[str, str, int]]
    errors: list[str]
    text: str


def open_in_browser(index: Path) -> PageCheck:
    """Load ``index`` (a file) in headless Chromium; skip the test when no browser can be driven."""
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        pytest.skip("selenium is not installed (pip install -e '.[test]')")
    for exe, pkg in ((CHROMIUM, "chromium"), (CHROMEDRIVER, "chromium-driver")):
        if not exe.exists():
            pytest.skip(f"no headless browser: {exe} not found (apt-get install {pkg})")
    profile = tempfile.mkdtemp(prefix="fingerloc-chromium-")
    opts = webdriver.ChromeOptions()
    opts.binary_location = str(CHROMIUM)
    for flag in (*FLAGS, f"--user-data-dir={profile}"):
        opts.add_argument(flag)
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    try:
        driver = webdriver.Chrome(options=opts, service=Service(str(CHROMEDRIVER)))
    except Exception as err:  # a browser that cannot start here (no display libraries, ...) is a skip, not a failure
        shutil.rmtree(profile, ignore_errors=True)
        pytest.skip(f"headless Chromium could not start: {type(err).__name__}: {str(err).splitlines()[0][:200]}")
    try:
        driver.set_page_load_timeout(60)
        driver.get(index.resolve().as_uri())
        images = driver.execute_script(
            "return Array.from(document.images).map(i => [i.getAttribute('src'), i.getAttribute('alt') || '',"
            " i.complete ? i.naturalWidth : 0]);"
        )
        title = driver.title
        text = driver.execute_script("return document.body.innerText;")
        logs = driver.get_log("browser")
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)
    errors = [e["message"] for e in logs if e.get("level") == "SEVERE"]
    return PageCheck(title=title, images=[(str(s), str(a), int(w)) for s, a, w in images], errors=errors, text=text)


def assert_page_ok(index: Path, *, min_images: int = 1) -> PageCheck:
    """Every image loads (naturalWidth > 0) and has alt text; no console error; at least ``min_images`` images."""
    page = open_in_browser(index)
    assert not page.errors, page.errors
    assert len(page.images) >= min_images, page.images
    broken = [src for src, _, w in page.images if w <= 0]
    assert not broken, f"images that did not load: {broken}"
    no_alt = [src for src, alt, _ in page.images if not alt.strip()]
    assert not no_alt, f"images without alt text: {no_alt}"
    return page
