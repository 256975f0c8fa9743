"""The quality report in a real browser: headless Chromium loads it offline, every image decodes.

Uses /usr/bin/chromium (or ``chromium`` on PATH); when missing and running as root with
apt-get, installs Debian's ``chromium`` package first (skips with the reason when that fails,
e.g. without network). The screenshot is kept under pytest's temporary folder (its path is
printed; set BIASGT_REPORT_SCREENSHOT=FILE.png to copy it somewhere).
"""

from __future__ import annotations

import html as html_lib
import json
import os
import re
import shutil
import struct
import subprocess
from pathlib import Path

import pytest

from reports.quality import SECTIONS, build_quality_report, stage_dirs
from test_reports import SEQ, _run_stages

pytestmark = pytest.mark.chromium

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--disable-dev-shm-usage", "--hide-scrollbars"]


def _find_chromium() -> str | None:
    for cand in ("/usr/bin/chromium", shutil.which("chromium"), shutil.which("chromium-browser")):
        if cand and os.access(cand, os.X_OK):
            return cand
    return None


@pytest.fixture(scope="module")
def chromium() -> str:
    found = _find_chromium()
    if found:
        return found
    if not hasattr(os, "geteuid") or os.geteuid() != 0 or shutil.which("apt-get") is None:
        pytest.skip("chromium is not installed and cannot be installed here (needs root and apt-get)")
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    try:
        subprocess.run(["apt-get", "update"], check=True, capture_output=True, timeout=900, env=env)
        subprocess.run(["apt-get", "install", "-y", "chromium"], check=True,
                       capture_output=True, timeout=1800, env=env)
    except (subprocess.CalledProcessError, subprocess.TimeoutExpired, OSError) as exc:
        tail = getattr(exc, "stderr", b"") or b""
        pytest.skip(f"could not install chromium with apt-get ({exc}; {tail[-300:]!r}): no network?")
    found = _find_chromium()
    if not found:
        pytest.skip("apt-get installed chromium but no chromium executable was found")
    return found


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("chromium")
    results = _run_stages(root)  # ingest, recover, validate of a simulation
    d = stage_dirs(results, SEQ)
    return build_quality_report(d["ingest"], recovery_dir=d["recovery"], validation_dir=d["validation"],
                                out_path=root / "report.html")


def _run(chromium: str, profile: Path, *args: str) -> subprocess.CompletedProcess:
    cmd = [chromium, *FLAGS, f"--user-data-dir={profile}", *args]
    try:
        return subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)
    except subprocess.TimeoutExpired:
        pytest.fail(f"chromium did not finish within 120 s: {' '.join(cmd)}")


#: Measures a page in an iframe of each width (srcdoc: same origin, so its layout is readable): the page's
#: sideways overflow, the widest image, and per table (by id) whether it fits its scroll box.
MEASURE_SCRIPT = """
window.addEventListener("load", function () {
  var out = {};
  document.querySelectorAll("iframe").forEach(function (f) {
    var d = f.contentDocument, root = d.documentElement, tables = {};
    d.querySelectorAll("table[id]").forEach(function (t) {
      var box = t.parentElement;
      tables[t.id] = {width: t.scrollWidth, box: box.clientWidth};
    });
    var img = 0;
    Array.prototype.forEach.call(d.images, function (i) { img = Math.max(img, i.getBoundingClientRect().right); });
    out[f.dataset.width] = {client: root.clientWidth, scroll: root.scrollWidth, img: img, tables: tables};
  });
  document.body.dataset.layout = JSON.stringify(out);
});
"""


def measure_widths(chromium: str, page_file: Path, widths: tuple[int, ...], work: Path) -> dict[str, dict]:
    """Layout figures of ``page_file`` at each viewport width (CSS px), read in headless Chromium: per width,
    ``client`` / ``scroll`` (the page's width and scroll width), ``img`` (right edge of the widest image) and
    ``tables`` (id -> its width and its box's)."""
    doc = html_lib.escape(page_file.read_text(encoding="utf-8"), quote=True)
    frames = "".join(f'<iframe data-width="{w}" style="width:{w}px;height:900px;border:0;display:block" '
                     f'srcdoc="{doc}"></iframe>' for w in widths)
    harness = work / "harness.html"
    harness.write_text(f"<!DOCTYPE html><html><body style='margin:0'>{frames}<script>{MEASURE_SCRIPT}</script>"
                       "</body></html>", encoding="utf-8")
    res = _run(chromium, work / "profile-measure", f"--window-size={max(widths) + 100},1000",
               "--virtual-time-budget=15000", "--dump-dom", harness.resolve().as_uri())
    assert res.returncode == 0, res.stderr[-2000:]
    found = re.search(r'<body[^>]*data-layout="([^"]*)"', res.stdout)
    assert found, res.stdout[-1000:]
    return json.loads(html_lib.unescape(found.group(1)))


def test_report_does_not_scroll_sideways_on_a_phone(chromium, report, tmp_path):
    layout = measure_widths(chromium, report, (390, 1280), tmp_path)
    for width, m in layout.items():
        assert m["scroll"] <= m["client"], (width, m)  # wide tables scroll in their own box, not the page
        assert m["img"] <= m["client"] + 1, (width, m)


def test_chromium_renders_report(chromium, report, tmp_path):
    url = report.resolve().as_uri()
    dom = _run(chromium, tmp_path / "profile-dom", "--virtual-time-budget=10000", "--dump-dom", url)
    assert dom.returncode == 0, dom.stderr[-2000:]
    html = dom.stdout
    body = re.search(r"<body\b[^>]*>", html)
    assert body, html[:500]
    # the inline script ran after load: every image decoded (naturalWidth > 0)
    assert 'data-broken-images="0"' in body.group(0), body.group(0)
    assert 'data-images="8"' in body.group(0), body.group(0)
    assert "The recovered bias integrates" in html and "better than a constant bias" in html
    for _, title in SECTIONS:
        assert title in html

    shot = tmp_path / "report.png"
    res = _run(chromium, tmp_path / "profile-shot", "--virtual-time-budget=10000", "--window-size=1280,7000",
               f"--screenshot={shot}", url)
    assert res.returncode == 0 and shot.is_file(), res.stderr[-2000:]
    data = shot.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = struct.unpack(">II", data[16:24])
    assert (width, height) == (1280, 7000)
    assert len(data) > 200_000  # figures and text, not a blank page
    print(f"screenshot: {shot}")
    target = os.environ.get("BIASGT_REPORT_SCREENSHOT")
    if target:
        shutil.copyfile(shot, target)
