"""The HTML report in a real browser: headless Chromium (Debian packages ``chromium`` and
``chromium-driver``) driven by selenium.

For a report written by harness.report (several checks, real PNG figures) and, when
``CPDI_BROWSER_REPORT`` names a report directory (e.g. ``reports/latest``), for that one too:

- every figure decodes (``naturalWidth > 0``) and is displayed with a non-zero size;
- every table-of-contents link lands on its section: after the click the URL's fragment is the
  section's id and the section's top is inside the viewport;
- the browser console shows no errors (level SEVERE);
- a screenshot of the first screen is saved next to the report (``screenshot.png``).

A deliberately broken page checks that the probes do see a broken figure, a console error and a
link to nowhere. Skipped, saying what to install, where Chromium or chromedriver is missing.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pytest  # noqa: E402

from harness import report  # noqa: E402
from harness.checks.base import CheckResult, Gate  # noqa: E402

CHROMIUM = next((p for p in (os.environ.get("CPDI_CHROMIUM"), shutil.which("chromium"), "/usr/bin/chromium")
                 if p and Path(p).is_file()), None)
CHROMEDRIVER = next((p for p in (os.environ.get("CPDI_CHROMEDRIVER"), shutil.which("chromedriver"),
                                 "/usr/bin/chromedriver") if p and Path(p).is_file()), None)

pytestmark = pytest.mark.skipif(
    CHROMIUM is None or CHROMEDRIVER is None,
    reason="the browser test needs headless Chromium and its driver: apt-get install chromium chromium-driver "
           f"(found chromium: {CHROMIUM or 'no'}, chromedriver: {CHROMEDRIVER or 'no'}); .ci/run installs them as root")

PROV = {"git_sha": "abc123def4567890", "dirty": False, "compiler": "GNU Fortran 12.2.0", "fflags": "-O3",
        "numpy": "2.3.5", "date": "2025-01-01T00:00:00Z"}
WIDTH, HEIGHT = 1280, 900
# No network on the test machines and none needed: every Chromium service that would reach out is off.
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--disable-dev-shm-usage", f"--window-size={WIDTH},{HEIGHT}"]


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is not installed (pyproject pins it)")
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    opts = Options()
    opts.binary_location = CHROMIUM
    for a in CHROMIUM_ARGS:
        opts.add_argument(a)
    opts.add_argument(f"--user-data-dir={tmp_path_factory.mktemp('chromium-profile')}")
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(options=opts, service=Service(executable_path=CHROMEDRIVER))
    driver.set_page_load_timeout(60)
    try:
        yield driver
    finally:
        driver.quit()


def _figure(path: Path, i: int) -> None:
    fig, ax = plt.subplots(figsize=(5, 3))
    ax.plot([0, 1, 2], [0, i, 2 * i], "o-")
    ax.set_title(f"figure {i}")
    fig.savefig(path, dpi=60)
    plt.close(fig)


def _write_report(out: Path) -> Path:
    """A report of six checks, each with a figure, tables and notes: long enough to scroll."""
    fig_dir = out / "figures"
    fig_dir.mkdir(parents=True)
    results = []
    for i in range(6):
        name = f"check_{i}"
        _figure(fig_dir / f"{name}.png", i)
        rows = "\n".join(f"| {j} | {j * 0.1:.2f} | {j * j} |" for j in range(12))
        results.append(CheckResult(
            name=name, requirement=f"requirement {i}: the solver does thing {i}",
            metrics={"error": 0.01 * i, "order": 2.0},
            gates=[Gate.at_most("error", 0.01 * i, 0.03), Gate.at_least("order", 2.0, 1.8)],
            figures=[f"{name}.png"], tables=[f"| n | x | y |\n|---|---|---|\n{rows}"],
            notes=[f"Note on **check {i}**."], wall_s=1.0 + i))
    report.write_report(out, results, PROV, quick=True)
    return out / "index.html"


# ---------------------------------------------------------------- probes (return lists of problems)
def figure_problems(driver) -> tuple[int, list[str]]:
    imgs = driver.find_elements("css selector", "img")
    bad = []
    for img in imgs:
        alt = img.get_attribute("alt")
        decoded = driver.execute_script("return arguments[0].complete && arguments[0].naturalWidth > 0;", img)
        driver.execute_script("arguments[0].scrollIntoView({block: 'center'});", img)
        size = img.size
        if not decoded:
            bad.append(f"figure {alt!r} does not decode (naturalWidth 0)")
        elif not img.is_displayed() or size["width"] <= 0 or size["height"] <= 0:
            bad.append(f"figure {alt!r} is not visible (displayed {img.is_displayed()}, size {size})")
    return len(imgs), bad


def toc_problems(driver) -> tuple[int, list[str]]:
    links = driver.find_elements("css selector", "nav.toc a[href^='#']")
    bad = []
    for i in range(len(links)):
        driver.execute_script("window.scrollTo(0, 0);")
        link = driver.find_elements("css selector", "nav.toc a[href^='#']")[i]
        target = link.get_attribute("href").split("#", 1)[1]
        link.click()
        where = driver.execute_script(
            "const e = document.getElementById(arguments[0]);"
            "if (!e) return null;"
            "return [e.getBoundingClientRect().top, window.innerHeight, location.hash];", target)
        if where is None:
            bad.append(f"contents link #{target}: no element with that id")
            continue
        top, inner, hash_ = where
        if hash_ != f"#{target}" or not (-1.0 <= top < inner):
            bad.append(f"contents link #{target}: section top at {top:.0f} px (viewport 0-{inner}), "
                       f"location.hash {hash_!r}")
    return len(links), bad


def console_errors(driver) -> list[str]:
    return [f"{e['level']}: {e['message']}" for e in driver.get_log("browser") if e["level"] == "SEVERE"]


def _open(driver, index: Path) -> None:
    driver.get_log("browser")  # drop what earlier pages logged
    driver.get(index.resolve().as_uri())
    driver.execute_script("window.scrollTo(0, 0);")


def _check_report(driver, index: Path) -> None:
    _open(driver, index)
    shot = index.parent / "screenshot.png"
    assert driver.save_screenshot(str(shot)), "the screenshot was not written"
    assert shot.stat().st_size > 1000
    n_fig, bad_fig = figure_problems(driver)
    n_toc, bad_toc = toc_problems(driver)
    errors = console_errors(driver)
    assert n_fig > 0 and n_toc > 0, f"{index}: {n_fig} figures, {n_toc} contents links"
    assert not bad_fig, "\n".join(bad_fig)
    assert not bad_toc, "\n".join(bad_toc)
    assert not errors, "browser console:\n" + "\n".join(errors)


def test_report_in_chromium(browser, tmp_path: Path) -> None:
    index = _write_report(tmp_path / "report")
    _check_report(browser, index)
    assert (tmp_path / "report" / "screenshot.png").is_file()


@pytest.mark.skipif(not os.environ.get("CPDI_BROWSER_REPORT"),
                    reason="set CPDI_BROWSER_REPORT=<report dir> (e.g. reports/latest) to test a verify report")
def test_verify_report_in_chromium(browser) -> None:
    index = Path(os.environ["CPDI_BROWSER_REPORT"]) / "index.html"
    assert index.is_file(), f"{index} does not exist"
    _check_report(browser, index)


def test_probes_see_a_broken_page(browser, tmp_path: Path) -> None:
    """The probes are not vacuous: a figure that does not decode, a console error and a contents
    link to a missing section are all reported."""
    page = tmp_path / "broken.html"
    page.write_text('<!DOCTYPE html><html><body><nav class="toc"><a href="#nowhere">x</a></nav>'
                    '<img alt="broken" src="data:image/png;base64,AAAA">'
                    '<script>console.error("deliberate error")</script></body></html>')
    _open(browser, page)
    n_fig, bad_fig = figure_problems(browser)
    n_toc, bad_toc = toc_problems(browser)
    assert n_fig == 1 and "does not decode" in bad_fig[0]
    assert n_toc == 1 and "no element" in bad_toc[0]
    assert any("deliberate error" in e for e in console_errors(browser))
