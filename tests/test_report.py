"""The report page as a person sees it: generated quick, opened in headless Chromium, checked, photographed."""

from __future__ import annotations

import base64
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from rayaccel.cli import main
from rayaccel.report import SECTIONS, find_bench_results, markdown_html

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")
TEST_SIDE = 32

NO_BROWSER = "needs Debian's chromium and chromium-driver (apt-get install -y chromium chromium-driver)"


def _fake_bench_results(folder: Path) -> Path:
    """A results folder as benchmarks/bench_structures.py writes it: a markdown table naming its chart."""
    folder.mkdir(parents=True)
    pixels = np.zeros((40, 60, 3), np.uint8)
    pixels[:, :30] = (200, 60, 60)
    Image.fromarray(pixels).save(folder / "bench_structures.png")
    (folder / "bench_structures.md").write_text(
        "# rayaccel against its peers\n\n- date: test\n\n![ratios to the best peer](bench_structures.png)\n\n"
        "## bunny\n\n| subject | build s | primary closest |\n|:---|---:|---:|\n"
        "| rayaccel bvh-binned | 0.27 | 1.07 |\n| Embree (embreex), 1 thread | 0.09 | 5.99 |\n")
    return folder


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    if CHROMIUM is None or CHROMEDRIVER is None:
        pytest.skip(NO_BROWSER)
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    folder = tmp_path_factory.mktemp("report")
    out = folder / "report.html"
    bench = _fake_bench_results(folder / "bench")
    assert main(["--quiet", "report", "--quick", "--size", str(TEST_SIDE), "--out", str(out),
                 "--bench-results", str(bench)]) == 0
    options = Options()
    options.binary_location = CHROMIUM
    for argument in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                     "--window-size=1280,900"):
        options.add_argument(argument)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    try:
        driver.get(out.as_uri())
        driver.execute_script("return document.fonts.ready")
        yield driver, out
    finally:
        driver.quit()


def test_page_loads_without_console_errors(page):
    driver, out = page
    severe = [entry for entry in driver.get_log("browser") if entry["level"] == "SEVERE"]
    assert severe == []
    assert driver.execute_script("return document.readyState") == "complete"
    assert "Quick run" in driver.find_element("css selector", ".banner").text


def test_every_image_decodes(page):
    driver, _ = page
    images = driver.execute_script(
        "return Array.from(document.images).map(i => [i.alt, i.complete, i.naturalWidth, i.src.slice(0, 22)])")
    charts = [alt for alt, *_ in images if alt.endswith(": chart")]
    assert len(charts) == len(SECTIONS)
    assert sum(alt == "render" for alt, *_ in images) >= 10
    assert any(alt == "ratios to the best peer" for alt, *_ in images)
    for alt, complete, width, source in images:
        assert complete and width > 0, alt
        assert source == "data:image/png;base64,", alt


def test_every_table_has_its_rows(page):
    driver, _ = page
    tables = driver.execute_script(
        "return Array.from(document.querySelectorAll('table')).map(t => ["
        "t.tHead ? t.tHead.rows[0].cells.length : 0, t.tBodies.length ? t.tBodies[0].rows.length : 0])")
    assert len(tables) >= len(SECTIONS) + 1
    for header_cells, body_rows in tables:
        assert header_cells >= 2 and body_rows >= 1


def test_contents_link_every_section_and_nothing_leaves_the_page(page):
    driver, out = page
    targets = driver.execute_script(
        "return Array.from(document.querySelectorAll('nav a')).map(a => a.getAttribute('href'))")
    assert len(targets) == len(SECTIONS) + 2
    for target in targets:
        assert driver.find_elements("css selector", target), target
    outside = driver.execute_script(
        "return Array.from(document.querySelectorAll('[src], link[href], script')).map(e => e.outerHTML.slice(0, 80))"
        ".filter(html => !html.includes('data:'))")
    assert outside == []
    text = driver.find_element("tag name", "body").text
    for label in ("CPU", "memory", "numba", "numpy", "Python"):
        assert label in text


def test_full_page_screenshot(page, tmp_path):
    driver, _ = page
    width, height = driver.execute_script(
        "return [document.documentElement.scrollWidth, document.documentElement.scrollHeight]")
    shot = driver.execute_cdp_cmd("Page.captureScreenshot", {
        "format": "png", "captureBeyondViewport": True,
        "clip": {"x": 0, "y": 0, "width": width, "height": height, "scale": 1}})
    path = tmp_path / "report.png"
    path.write_bytes(base64.b64decode(shot["data"]))
    with Image.open(path) as picture:
        assert picture.size == (width, height) and height > 2000


def test_newest_bench_results_are_found_and_inlined(tmp_path):
    assert find_bench_results(tmp_path / "absent") is None and find_bench_results(tmp_path) is None
    older = _fake_bench_results(tmp_path / "results" / "older")
    newer = _fake_bench_results(tmp_path / "results" / "newer")
    os.utime(older / "bench_structures.md", (1e9, 1e9))
    assert find_bench_results(tmp_path / "results") == newer / "bench_structures.md"
    (newer / "bench_structures.png").unlink()
    text = markdown_html(newer / "bench_structures.md", drop_title=True)
    assert "<table>" in text and "<h4>bunny</h4>" in text and "rayaccel against its peers" not in text
    assert "<img" not in text and "bench_structures.png was not written" in text
