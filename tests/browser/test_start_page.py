"""The start page in headless Chromium: three sections, and their links lead somewhere."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.browser

SECTIONS = {
    "calibration": "Camera calibration",
    "designer": "Marker designer",
    "live": "Live view",
}


def test_start_page_sections_and_link(page, live_server):
    page.goto(live_server + "/")
    assert "Drovisio" in page.title()
    for section_id, heading in SECTIONS.items():
        section = page.locator(f"section#{section_id}")
        assert section.is_visible(), section_id
        assert section.locator("h2").inner_text().strip() == heading
        assert section.locator("a").first.is_visible()

    page.locator("section#designer a").first.click()
    page.wait_for_url(live_server + "/designer")
    assert page.locator("h1").inner_text().strip() == "Marker designer"
    assert "Marker designer" in page.title()


def test_start_page_fits_a_phone(browser, live_server):
    context = browser.new_context(viewport={"width": 360, "height": 740}, is_mobile=True,
                                  has_touch=True)
    try:
        pg = context.new_page()
        pg.goto(live_server + "/")
        # No horizontal scrolling on a small phone, and buttons are big enough to hit.
        assert pg.evaluate("document.documentElement.scrollWidth") <= 360
        box = pg.locator("section#live a").first.bounding_box()
        assert box and box["height"] >= 44
    finally:
        context.close()
