"""The command line: one clear line and a non-zero exit for bad input, never a traceback."""
import subprocess
import sys

import pytest

from apmcal.cli import main


def run_cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "apmcal", *args], capture_output=True, text=True,
                          timeout=120, cwd=cwd)


def assert_one_line_error(proc, *fragments):
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    for fragment in fragments:
        assert fragment in lines[0]


def test_missing_file(tmp_path):
    missing = tmp_path / "nope.tlog"
    assert_one_line_error(run_cli("log", str(missing)), str(missing))


def test_unknown_format(tmp_path):
    junk = tmp_path / "junk.xyz"
    junk.write_bytes(bytes(range(256)) * 40)
    assert_one_line_error(run_cli("log", str(junk)), str(junk))


def test_empty_file(tmp_path):
    empty = tmp_path / "empty.bin"
    empty.write_bytes(b"")
    assert_one_line_error(run_cli("log", str(empty)), str(empty))


def test_unknown_method_is_an_argparse_error(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["log", "x.tlog", "--method", "magic"])
    assert exc.value.code != 0


# ---------------------------------------------------------------------------------------------
import json
import os
import re
import shutil
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from apmcal import cli

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "logs" / "ferraris.tlog"
SITE = ["--lat", "5.6037", "--lon", "-0.187"]


def still_csv(path: Path) -> Path:
    """Ten seconds of a level, still IMU in the default CSV layout (no firmware to write for)."""
    rng = np.random.default_rng(1)
    n = 1000
    acc = np.array([0.1, -0.2, -9.8]) + rng.normal(0, 0.02, (n, 3))
    gyr = np.array([0.01, -0.02, 0.005]) + rng.normal(0, 0.002, (n, 3))
    rows = ["t,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z"]
    rows += [",".join(f"{v:.6f}" for v in (i * 0.01, *acc[i], *gyr[i])) for i in range(n)]
    path.write_text("\n".join(rows) + "\n")
    return path


def one_line_err(capsys) -> str:
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1, err
    assert "Traceback" not in err[0] and "internal error" not in err[0]
    return err[0]


def test_firmware_hint_names_options_that_parse_and_work(tmp_path, capsys):
    """The hint for a CSV file with --param-file must be a command that actually runs."""
    csv = still_csv(tmp_path / "still.csv")
    out = tmp_path / "out.param"
    assert main(["log", str(csv), "--param-file", str(out), "--quiet"]) == 2
    line = one_line_err(capsys)
    choices = re.findall(r"--firmware (\S+?)(?:\s|$|,)", line)
    assert len(choices) == 2, line
    for choice in choices:
        args = cli.build_parser().parse_args(["log", str(csv), "--firmware", choice])
        assert args.firmware == choice
        assert main(["log", str(csv), "--param-file", str(out), "--firmware", choice,
                     "--quiet"]) == 0
        assert "INS_GYROFFS_X" in out.read_text()
        out.unlink()


def test_json_is_written_when_the_param_file_step_fails(tmp_path, capsys):
    csv = still_csv(tmp_path / "still.csv")
    js = tmp_path / "out.json"
    assert main(["log", str(csv), "--param-file", str(tmp_path / "out.param"),
                 "--json", str(js)]) == 2
    assert "--firmware" in one_line_err(capsys)
    result = json.loads(js.read_text())
    assert result["method"] == "static" and "acc" in result and "gyr" in result
    assert "--firmware" in result["param_file_error"]
    assert not (tmp_path / "out.param").exists()


@pytest.mark.parametrize("argv, option", [
    (["live", "udp:127.0.0.1:1", "--rate", "0"], "--rate"),
    (["live", "udp:127.0.0.1:1", "--rate", "-5"], "--rate"),
    (["live", "udp:127.0.0.1:1", "--rate", "1001"], "--rate"),
    (["live", "udp:127.0.0.1:1", "--rate", "12.5"], "--rate"),
    (["live", "udp:127.0.0.1:1", "--duration", "0"], "--duration"),
    (["live", "udp:127.0.0.1:1", "--duration", "-3"], "--duration"),
    (["live", "udp:127.0.0.1:1", "--duration", "nan"], "--duration"),
    (["live", "udp:127.0.0.1:1", "--duration", "inf"], "--duration"),
    (["live", "udp:127.0.0.1:1", "--hold", "0"], "--hold"),
    (["live", "udp:127.0.0.1:1", "--face-timeout", "-1"], "--face-timeout"),
    (["live", "udp:127.0.0.1:1", "--lat", "91"], "--lat"),
    (["log", "x.tlog", "--min-still", "0"], "--min-still"),
    (["log", "x.tlog", "--min-still", "nan"], "--min-still"),
    (["log", "x.tlog", "--lat", "-90.5"], "--lat"),
    (["log", "x.tlog", "--lat", "nan"], "--lat"),
    (["log", "x.tlog", "--lat", "5", "--lon", "180.1"], "--lon"),
    (["log", "x.tlog", "--lat", "5", "--lon", "-inf"], "--lon"),
    (["log", "x.tlog", "--lon", "8.5"], "--lon"),          # longitude alone would be unused
])
def test_bad_option_values_are_one_line_usage_errors(argv, option, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert option in one_line_err(capsys)


def test_option_values_at_their_limits_parse():
    args = cli.build_parser().parse_args(
        ["live", "udp:127.0.0.1:1", "--rate", "1000", "--face-timeout", "1e-3", "--duration",
         "0.5", "--hold", "1e-3", "--lat", "-90", "--lon", "180", "--min-still", "0.1"])
    assert (args.rate, args.face_timeout, args.lat, args.lon) == (1000, 1e-3, -90.0, 180.0)
    assert cli.build_parser().parse_args(["log", "x.tlog", "--lat", "47.4"]).lon is None


@pytest.mark.parametrize("option", ["--json", "--param-file"])
@pytest.mark.parametrize("kind", ["missing_dir", "is_dir"])
def test_unwritable_outputs_fail_in_one_line_before_any_work(tmp_path, capsys, monkeypatch,
                                                             option, kind):
    import apmcal.sources

    monkeypatch.setattr(apmcal.sources, "read_log", never_called)   # refused before reading
    target = tmp_path / "no" / "such" / "out" if kind == "missing_dir" else tmp_path
    assert main(["log", str(SAMPLE), *SITE, option, str(target), "--quiet"]) == 2
    line = one_line_err(capsys)
    assert str(target) in line
    assert ("does not exist" if kind == "missing_dir" else "is a directory") in line


def never_called(*args, **kwargs):
    raise AssertionError("should have been refused before this")


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0,
                    reason="root may write anywhere: no permission error to provoke")
def test_output_in_read_only_directory(tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        assert main(["log", str(SAMPLE), "--json", str(ro / "out.json"), "--quiet"]) == 2
        assert "permission denied" in one_line_err(capsys)
    finally:
        ro.chmod(0o700)


def test_json_write_failure_at_the_write_point_is_one_line(tmp_path, capsys, monkeypatch):
    """Past the early check (a directory appearing meanwhile, a full disk): still one line."""
    monkeypatch.setattr(cli.common, "check_writable", lambda path, what: None)
    assert main(["log", str(SAMPLE), *SITE, "--json", str(tmp_path), "--quiet"]) == 2
    line = one_line_err(capsys)
    assert str(tmp_path) in line and "cannot write JSON file" in line


@pytest.mark.parametrize("extra", [[], ["--json", "{missing}/r.json"],
                                   ["--upload", "--backup", "{missing}/b.param"]])
def test_unwritable_live_outputs_are_refused_before_connecting(tmp_path, capsys, monkeypatch,
                                                               extra):
    import apmcal.sources.live

    monkeypatch.setattr(apmcal.sources.live, "VehicleLink", never_called)
    missing = tmp_path / "missing"
    extra = [a.format(missing=missing) for a in extra]
    save_log = str(missing / "live.tlog") if not extra else str(tmp_path / "live.tlog")
    assert main(["live", "udp:127.0.0.1:9", "--save-log", save_log, *extra]) == 2
    line = one_line_err(capsys)
    assert str(missing) in line and "does not exist" in line
    assert not missing.exists() and not (tmp_path / "live.tlog").exists()


def test_numpy_runtime_warnings_do_not_reach_the_user(tmp_path, capsys, monkeypatch):
    from apmcal.report import session as report

    summarize = report.summarize

    def noisy_summarize(contents):
        np.mean(np.array([]))                       # "Mean of empty slice"
        np.array([0.0]) / np.array([0.0])           # "invalid value encountered"
        return summarize(contents)

    monkeypatch.setattr(report, "summarize", noisy_summarize)
    csv = still_csv(tmp_path / "still.csv")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert main(["log", str(csv), "--summary-only", "--quiet"]) == 0
        assert [str(w.message) for w in caught] == []
        assert main(["--debug", "log", str(csv), "--summary-only", "--quiet"]) == 0
        assert any(issubclass(w.category, RuntimeWarning) for w in caught)   # --debug shows them
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("name", ["flight[1].tlog", "run[blue].tlog"])
def test_brackets_in_file_names_and_units_are_printed_literally(tmp_path, name):
    shutil.copyfile(SAMPLE, tmp_path / name)
    proc = run_cli("log", name, *SITE, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ""                        # no stray warning lines either
    assert name in proc.stdout
    for unit in ("offset [m/s²]", "offset [rad/s]", "offset [mGauss]", "rate [Hz]"):
        assert unit in proc.stdout
    assert "mag: field magnitude" in proc.stdout    # the solvers' report lines are shown


class FakeLink:
    def __init__(self, connection, **kwargs):
        self.connection = connection

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


@pytest.mark.parametrize("skipped", [None, [], ["FOO_BAR", "BAZ"]])
def test_restore_reports_names_the_vehicle_does_not_have(tmp_path, capsys, monkeypatch, skipped):
    import apmcal.link.upload
    import apmcal.sources.live

    result = SimpleNamespace(written={"INS_ACCOFFS_X": 0.0})
    if skipped is not None:                        # an UploadReport before/after 'skipped'
        result.skipped = skipped
    monkeypatch.setattr(apmcal.sources.live, "VehicleLink", FakeLink)
    monkeypatch.setattr(apmcal.link.upload, "restore_params", lambda link, path, **kw: result)
    (tmp_path / "b.param").write_text("INS_ACCOFFS_X 0\n")    # read before connecting
    assert main(["restore", "fake:vehicle", str(tmp_path / "b.param")]) == 0
    out = capsys.readouterr().out
    assert "restored 1 parameters" in out
    if skipped:
        assert "skipped 2 names the vehicle does not have: FOO_BAR, BAZ" in out
    else:
        assert "skipped" not in out


def test_upload_reports_skipped_names(tmp_path, capsys, monkeypatch):
    import apmcal.link.upload
    import apmcal.sources.live

    param = tmp_path / "new.param"
    param.write_text("INS_ACCOFFS_X 0.1\n")
    result = SimpleNamespace(written={"INS_ACCOFFS_X": 0.1}, skipped=["NOPE"])
    monkeypatch.setattr(apmcal.sources.live, "VehicleLink", FakeLink)
    monkeypatch.setattr(apmcal.link.upload, "upload_params", lambda *a, **k: result)
    assert main(["upload", "fake:vehicle", str(param), "--backup", str(tmp_path / "b.param")]) == 0
    assert "skipped 1 names the vehicle does not have: NOPE" in capsys.readouterr().out


def test_unwritable_backup_is_refused_before_connecting(tmp_path, capsys, monkeypatch):
    import apmcal.sources.live

    monkeypatch.setattr(apmcal.sources.live, "VehicleLink", never_called)
    param = tmp_path / "new.param"
    param.write_text("INS_ACCOFFS_X 0.1\n")
    backup = tmp_path / "missing" / "b.param"
    assert main(["upload", "udp:127.0.0.1:9", str(param), "--backup", str(backup)]) == 2
    assert str(backup) in one_line_err(capsys)


def test_recording_open_failure_at_the_write_point_is_one_line(tmp_path, capsys, monkeypatch):
    """Past the early check, VehicleLink's own open() of the recording fails: still one line."""
    import apmcal.sources.live

    def link_opening(connection, record_to=None, **kwargs):
        open(record_to, "wb")          # what VehicleLink does once the vehicle answered

    monkeypatch.setattr(cli.common, "check_writable", lambda path, what: None)
    monkeypatch.setattr(apmcal.sources.live, "VehicleLink", link_opening)
    target = tmp_path / "missing" / "live.tlog"
    assert main(["live", "udp:127.0.0.1:9", "--save-log", str(target)]) == 2
    line = one_line_err(capsys)
    assert str(target) in line and "cannot write recording" in line


def test_the_command_line_builds_without_the_scientific_stack():
    """``apmcal --help`` (and every usage error) answers before numpy's dependants load: the
    parser's help texts read only light modules (issue 10: lazy imports)."""
    import subprocess
    import sys

    code = ("import sys; from apmcal.cli import build_parser; build_parser(); "
            "print(sorted(m for m in ('pandas', 'scipy', 'pymavlink', 'matplotlib') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "[]", out


def test_piped_report_verdict_first_no_jargon_no_wrapped_numbers():
    """`apmcal log` into a pipe (not a terminal): the verdict before the numbers, no specialist
    lines, no line break inside a number or a parenthesised vector, the sign of COMPASS_OFS
    explained."""
    proc = run_cli("log", str(SAMPLE), *SITE)
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    lines = out.splitlines()
    assert out.index("verdict: ") < out.index("method: ") < out.index("acc: offset")
    for line in lines:
        assert len(line) <= 100, line                        # wrapped at 100 characters
        if " = (" in line:                                   # a vector is never broken
            assert line.count("(") == line.count(")"), line  # (the matrix spans 3 lines)
        # a line broken inside a list or a number ends in "," or starts with its digits
        assert not line.rstrip().endswith(",") and not re.match(r"[-+]?[\d.]", line), line
    for jargon in ("seed 0", "antithetic", "Jacobian", "rank", "second-order fit bias"):
        assert jargon not in out
    assert "COMPASS_OFS is minus the offset shown above" in out
    acc = next(ln for ln in lines if "acc: offset" in ln)
    assert re.fullmatch(r"  acc: offset \[m/s²\] = \([^()]+\) ± \([^()]+\)", acc), acc
