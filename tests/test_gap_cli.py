"""``apmcal gap`` end to end on the bundled sample ``logs/gap.bin``.

The sample is a simulated session (the ``diagnosis`` script) of a board whose only error
beyond the nominal model is a temperature drift (see logs/README.md for the command): the
diagnosis must find that effect, recover its coefficients (checked against the injected truth,
``logs/gap.truth.json``), write the files it promises, and its twin file must make the
simulator behave like the board.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from apmcal.cli import main

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "logs" / "gap.bin"
TRUTH = json.loads((ROOT / "logs" / "gap.truth.json").read_text())
SITE = ["--lat", "5.6037", "--lon", "-0.187"]


@pytest.fixture(scope="module")
def diagnosed(tmp_path_factory):
    out = tmp_path_factory.mktemp("gap")
    code = main(["gap", str(SAMPLE), *SITE, "--json", str(out / "gap.json"),
                 "--report", str(out / "report"), "--write-twin", str(out / "twin.json"),
                 "--quiet"])
    return code, out, json.loads((out / "gap.json").read_text())


def test_the_injected_effect_is_found_and_closes_the_gap(diagnosed):
    code, _, result = diagnosed
    assert code == 0
    assert result["selected"] == ["temperature_drift"]
    first = result["effects"][0]
    assert first["name"] == "temperature_drift" and first["significant"]
    assert first["shrink_heldout"] > 0.95
    assert result["gap"]["heldout"] > 0.1          # a large gap before ...
    assert abs(result["after"]["heldout"]) < 0.01 * result["gap"]["heldout"]   # ... gone after
    # every other candidate is explained by it, or was never supported
    assert [e["name"] for e in result["effects"] if e["significant"]] == ["temperature_drift"]


def test_json_layout_is_the_documented_one(diagnosed):
    _, _, result = diagnosed
    assert result["schema"] == 1
    for key in ("total", "heldout", "breakdown", "breakdown_heldout"):
        assert key in result["gap"]
    for e in result["effects"]:
        assert {"name", "significant", "supported_alone", "not_tested"} <= set(e)
        if not e["not_tested"]:
            assert {"shrink_heldout", "evidence_nats", "gap_heldout", "params"} <= set(e)
    # best first: the selected combination (what it loses without each), then the rest
    names = [e["name"] for e in result["effects"]]
    assert names[:len(result["selected"])] == result["selected"]
    needed = [result["effects"][i]["evidence_in_combination_nats"]
              for i in range(len(result["selected"]))]
    assert needed == sorted(needed, reverse=True)
    evidence = [e["evidence_nats"] for e in result["effects"][len(result["selected"]):]
                if not e["not_tested"] and e["supported_alone"]]
    assert evidence == sorted(evidence, reverse=True)
    assert set(result["noise_structure"]) == {"acc", "gyr", "mag"}


def test_breakdown_parts_add_up_to_the_gap(diagnosed):
    _, _, result = diagnosed
    for gap_key, parts_key in (("total", "breakdown"), ("heldout", "breakdown_heldout")):
        total = result["gap"][gap_key]
        for split, parts in result["gap"][parts_key].items():
            assert sum(parts.values()) == pytest.approx(total, rel=1e-9, abs=1e-12), split


def test_temperature_coefficients_match_the_injected_ones(diagnosed):
    _, _, result = diagnosed
    params = result["effects"][0]["params"]
    injected = TRUTH["effects"]["temperature"]
    for key in ("gyro_coef", "acc_coef"):
        value, sigma = np.array(params[key]["value"]), np.array(params[key]["sigma"])
        truth = np.array(injected[key])
        np.testing.assert_allclose(value, truth, rtol=0.08, err_msg=key)
        assert np.all(np.abs(value - truth) < 4 * sigma), (key, value, truth, sigma)


def test_report_has_its_figures(diagnosed):
    _, out, _ = diagnosed
    text = (out / "report" / "report.md").read_text()
    assert "temperature_drift" in text
    for png in ("segments.png", "bands.png", "psd.png", "allan.png", "temperature.png"):
        assert (out / "report" / png).stat().st_size > 1000
        assert f"({png})" in text


def test_twin_file_is_a_sitl_truth_with_the_selected_effect(diagnosed):
    from apmcal.sensor_model.truth import NOMINAL_EFFECTS, Truth

    _, out, _ = diagnosed
    twin = Truth.load(out / "twin.json")
    on = {name for name, state in twin.enabled.items() if state}
    assert on == set(NOMINAL_EFFECTS) | {"temperature_drift"}
    np.testing.assert_allclose(twin.temperature["gyro_coef"],
                               TRUTH["effects"]["temperature"]["gyro_coef"], rtol=0.08)


@pytest.mark.parametrize("argv, fragment", [
    (["gap", "/nonexistent/x.bin"], "/nonexistent/x.bin"),
    (["gap", str(ROOT / "logs" / "tumble.bin")], "still"),
    (["gap", str(SAMPLE), "--effects", "warp_drive"], "warp_drive"),
    (["gap", str(SAMPLE), "--lon", "3"], "--lat"),
    (["gap", str(SAMPLE), "--report", str(ROOT / "logs" / "README.md")], "not a directory"),
    (["gap"], "log file"),
])
def test_bad_input_is_one_line_and_exit_2(argv, fragment, capsys):
    try:
        code = main(argv)
    except SystemExit as exc:           # usage errors end in argparse's exit
        code = exc.code
    assert code == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and fragment in err[0], err
    assert "Traceback" not in err[0]


def test_the_twin_of_the_board_behaves_like_it(diagnosed, tmp_path):
    """Close the loop: the simulator run with the twin file makes a log in which the same
    effect is found with the same coefficients, and nothing else — the gap is gone once it
    is modelled."""
    _, out, real = diagnosed
    log = tmp_path / "twin.bin"
    subprocess.run([sys.executable, "-m", "apmcal_sim.makelog", "--script", "diagnosis", "--out",
                    str(log), "--seed", "5", "--rate", "50", "--twin", str(out / "twin.json")],
                   check=True, cwd=ROOT, timeout=300)
    json_out = tmp_path / "twin_gap.json"
    assert main(["gap", str(log), *SITE, "--json", str(json_out), "--quiet",
                 "--effects", "temperature_drift,bias_drift,bias_random_walk,lowpass_filter,"
                 "uniform_noise"]) == 0
    twin = json.loads(json_out.read_text())
    assert twin["selected"] == ["temperature_drift"]
    assert 0.5 < twin["gap"]["heldout"] / real["gap"]["heldout"] < 2.0
    assert abs(twin["after"]["heldout"]) < 0.01 * twin["gap"]["heldout"]
    fitted = {key: np.array(twin["effects"][0]["params"][key]["value"])
              for key in ("gyro_coef", "acc_coef")}
    for key, value in fitted.items():
        np.testing.assert_allclose(value, real["effects"][0]["params"][key]["value"],
                                   rtol=0.1, atol=2e-6 if key == "gyro_coef" else 2e-4)


def test_the_log_read_in_a_worker_is_the_log_read_here():
    """diagnose_file reads and cuts the log in a forked process: what comes back is the
    session this process would have made, array for array."""
    from dataclasses import fields

    from apmcal.calibration.log import Options
    from apmcal.diagnosis.compute import workers
    from apmcal.diagnosis.reading import LogReading
    from apmcal.diagnosis.session.log import session_from_log
    from apmcal.sources import read_log

    opts = Options(lat_deg=5.6037, lon_deg=-0.187)
    _, [(there, warnings, error)] = workers.beside(LogReading(str(SAMPLE), opts),
                                                  [("session", ())], lambda: None)
    here = session_from_log(read_log(SAMPLE), opts)
    assert error is None and isinstance(warnings, list)
    for f in fields(here):
        a, b = getattr(here, f.name), getattr(there, f.name)
        if isinstance(a, np.ndarray):
            assert np.array_equal(a, b, equal_nan=True), f.name
    assert np.array_equal(here.pieces.i0, there.pieces.i0)
    assert [(h.i0, h.i1) for h in here.holds] == [(h.i0, h.i1) for h in there.holds]
    _, [(none, _, refused)] = workers.beside(LogReading("/nonexistent/x.bin", opts),
                                            [("session", ())], lambda: None)
    assert none is None and "/nonexistent/x.bin" in str(refused)


def test_the_program_ends_with_its_output_written_and_its_status(tmp_path):
    """``python -m apmcal gap`` ends without Python's teardown (apmcal.cli.entry): everything
    printed and written must still be there, and the exit status must be the command's."""
    out = tmp_path / "gap.json"
    done = subprocess.run([sys.executable, "-m", "apmcal", "gap", str(SAMPLE), *SITE,
                           "--effects", "temperature_drift", "--json", str(out)],
                          capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stdout.rstrip().endswith(f"wrote {out}")
    assert json.loads(out.read_text())["selected"] == ["temperature_drift"]
    bad = subprocess.run([sys.executable, "-m", "apmcal", "gap", str(tmp_path / "none.bin")],
                         capture_output=True, text=True, cwd=tmp_path)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "none.bin" in bad.stderr


@pytest.mark.skipif(sys.platform == "win32", reason="process groups and SIGINT are POSIX")
def test_ctrl_c_during_the_diagnosis_is_one_line_and_130(tmp_path):
    """Ctrl-C reaches the whole process group (the forked workers too): the workers leave it
    to the main process, which stops them and says so in one line."""
    import os
    import signal
    import time

    proc = subprocess.Popen([sys.executable, "-m", "apmcal", "gap", str(SAMPLE), *SITE],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=tmp_path, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    time.sleep(2.0)         # reading, importing or diagnosing: each must end the same way
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130
    assert err.strip().splitlines() == ["apmcal: interrupted (Ctrl-C)"]


def test_the_report_page_opens_with_the_consoles_advice_and_renders_its_markdown(diagnosed,
                                                                                tmp_path):
    """The gap page (index.html, rendered by headless Chromium) opens with the console's
    first lines, the action in words, before any figure in nats; its Markdown is rendered (no
    literal *emphasis*, "How this was computed" a list of whole items) and no table header is
    empty."""
    import io
    import re

    from rich.console import Console
    from test_html_report import CHROMIUM, chromium

    from apmcal.diagnosis.output.result import GapResult
    from apmcal.diagnosis.output.summary import print_summary

    if CHROMIUM is None:
        pytest.skip("headless Chromium not installed (.ci/run installs Debian's chromium)")
    _, out, _ = diagnosed
    buf = io.StringIO()
    print_summary(GapResult.load(out / "gap.json"), Console(file=buf, width=400,
                                                             color_system=None))
    first = buf.getvalue().splitlines()[0].strip().replace("`", "")   # `code` is code there
    dom = chromium(out / "report" / "index.html", tmp_path, "--dump-dom").stdout
    text = re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", dom))
    start = text.index("What to do")
    assert text.index(first[:60]) > start, (first, text[:600])
    assert text.index(first[:60]) < text.index("nats")
    assert not re.search(r"(?<![\w*])\*[A-Za-z][^*<]*\*", text), "literal *emphasis* on the page"
    assert "**" not in text
    assert not re.search(r"<th>\s*</th>", dom), "an empty table header"
    method = dom[dom.index("How this was computed"):]
    assert re.search(r"<ul>\s*<li><b>Real and twin\.</b> The log's samples", method)
    assert "<em>nominal model</em>" in method
