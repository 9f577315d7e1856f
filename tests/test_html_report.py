"""The HTML report (--report DIR): one self-contained DIR/index.html for log, tcal and gap,
rendered by headless Chromium (not blank: the verdict in the DOM, a screenshot with contrast)
and loading nothing from the network (no http(s) URL in the page)."""
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from apmcal.cli import main

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def self_contained(page: Path) -> str:
    text = page.read_text(encoding="utf-8")
    assert not re.search(r"https?://", text), "the page refers to the network"
    assert not re.search(r"<(script|link)\b", text), "the page loads scripts or style sheets"
    return text


def chromium(page: Path, tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([CHROMIUM, *FLAGS, f"--user-data-dir={tmp_path / 'profile'}", *args,
                           page.as_uri()], capture_output=True, text=True, timeout=120)


def rendered(page: Path, tmp_path: Path, expect: str) -> None:
    """Chromium's DOM holds ``expect`` and its screenshot is not one flat colour."""
    if CHROMIUM is None:
        pytest.skip("headless Chromium not installed (.ci/run installs Debian's chromium)")
    dom = chromium(page, tmp_path, "--dump-dom")
    assert expect in dom.stdout, dom.stderr[-2000:]
    shot = tmp_path / "shot.png"
    chromium(page, tmp_path, f"--screenshot={shot}", "--window-size=1000,1400")
    import matplotlib.image as mpimg

    pixels = mpimg.imread(shot)
    assert float(np.std(pixels[..., :3])) > 0.05, "the screenshot is blank"


def test_log_report_is_self_contained_and_renders(tmp_path):
    out = tmp_path / "r"
    assert main(["log", str(ROOT / "logs" / "ferraris.tlog"), "--report", str(out),
                 "--quiet"]) == 0
    text = self_contained(out / "index.html")
    assert text.count("data:image/png;base64,") == 3      # accelerometer, compass, gyro
    assert text.index("verdict:") < text.index("<img")
    rendered(out / "index.html", tmp_path, "verdict:")


def test_tcal_report_is_self_contained_and_renders(tmp_path):
    out = tmp_path / "t"
    assert main(["tcal", str(ROOT / "logs" / "warmup.bin"), "--report", str(out),
                 "--quiet"]) == 0
    text = self_contained(out / "index.html")
    assert "data:image/png;base64," in text and "proposed" in text
    rendered(out / "index.html", tmp_path, "temperature calibration")


def test_gap_report_page_from_its_figures(tmp_path):
    """The gap report's Markdown and PNGs turned into one page (no gap run: a small report.md
    and figure stand in, as write_report leaves them)."""
    import matplotlib

    from apmcal.diagnosis.output.html import write_index

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(3, 2))
    fig.gca().bar([0, 1], [1, 2])
    fig.savefig(tmp_path / "gap_by_sensor.png")
    plt.close(fig)
    (tmp_path / "report.md").write_text("# apmcal gap — x.bin\n\nThe gap lies in the gyro.\n\n"
                                        "![gap by sensor](gap_by_sensor.png)\n")
    page = write_index(tmp_path)
    text = self_contained(page)
    assert "data:image/png;base64," in text and "The gap lies in the gyro." in text
    rendered(page, tmp_path, "The gap lies in the gyro.")
