"""The dataset page in headless Chromium at 1280 and 390 CSS px, on a run with PASS, WARN and FAIL rows:
the page never scrolls sideways, the decision columns fit at 1280 without scrolling, the figure fits.
"""

from __future__ import annotations

import pytest

from reports.dataset import build_dataset_report
from test_dataset_report import _recovery, _validation, _write, results  # noqa: F401  (the fixture: PASS, WARN, FAIL and an unvalidated row)
from test_report_chromium import chromium, measure_widths  # noqa: F401  (chromium: the fixture)

pytestmark = pytest.mark.chromium


def test_dataset_page_fits_a_desktop_and_a_phone(chromium, results, tmp_path):  # noqa: F811
    # rows as wide as a real run's: long names, a position tracker, a long leading reason
    _write(results, "sim_handheld_test_01", _validation("PASS", [], reference={"kind": "state"}),
           _recovery("mocap0", 0.0021, 0.0003, 1.0), 0.012)
    _write(results, "sim_cart_leica_01", _validation(
        "WARN", ["too uncertain: the recovered bias's sigma allows it to be no better than a constant bias"],
        reference={"kind": "state"}), _recovery("leica0", -0.0074, 0.015, 7.3, kind="position_tracker"), 0.011)
    page = build_dataset_report(results)
    layout = measure_widths(chromium, page, (1280, 390), tmp_path)
    for width, m in layout.items():
        assert m["scroll"] <= m["client"], (width, m)  # no sideways scroll of the page body
        assert m["img"] <= m["client"] + 1, (width, m)
        assert set(m["tables"]) >= {"sequences-table", "details-table", "table-i"}
    glance = layout["1280"]["tables"]["sequences-table"]
    assert glance["width"] <= glance["box"], glance  # every decision column visible without scrolling
