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


def test_the_tcal_page_opens_with_what_the_console_says_it_proposes(tmp_path, capsys):
    """`apmcal tcal` says first what it proposes, in words, and its page opens with the same
    words: on the warm-up sample it proposes the calibration, on the six-face sample (10 °C,
    no significant drift) nothing."""
    for name, said in (("warmup.bin", "IMU 0: proposed — enable its temperature calibration"),
                       ("ferraris.tlog", "IMU 0: nothing proposed (INS_TCAL1_*)")):
        out = tmp_path / name
        assert main(["tcal", str(ROOT / "logs" / name), "--report", str(out)]) == 0
        console = capsys.readouterr().out
        assert console.startswith(said), console[:300]
        if CHROMIUM is None:
            continue
        dom = chromium(out / "index.html", tmp_path, "--dump-dom").stdout
        text = re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", dom))
        first_words = " ".join(console.split()[:12])
        assert first_words in text, (first_words, text[:500])
        assert text.index(first_words) < text.index("Figures")


def test_a_figure_title_is_never_cut():
    """The gap report's figures are saved by plots.save, which shrinks a title wider than its
    axes (or past the figure's edge) until it fits; checked on the geometry and titles that
    were cut before (two panels of 4.2 in)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from apmcal.diagnosis.output.plots import fits, save

    fig, axes = plt.subplots(1, 2, figsize=(8.4, 3.4))
    for ax, sensor in zip(axes, ("gyr", "acc")):
        ax.plot([25, 36], [0, 1])
        ax.set_title(f"{sensor}: nominal-model residual vs temperature, a longer title still")
    save(fig, Path(matplotlib.get_cachedir()) / "apmcal-title-test.png")
    renderer = fig.canvas.get_renderer()
    boxes = [ax.title.get_window_extent(renderer) for ax in axes]
    assert all(fits(b, fig.bbox) for b in boxes)
    assert boxes[0].x1 <= boxes[1].x0, "the titles overlap"
    plt.close(fig)
