"""Errors early and plain: output paths tried before any work, a sub-command's errors pointing
to its own help, unresolvable hosts said at once, a file that is no log called that, and the
parameter file formats (.param, Mission Planner's comma form, QGroundControl's .params)."""
import time
from pathlib import Path

import pytest

from apmcal.ardupilot.paramfile import read_param_file, write_param_file
from apmcal.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "logs" / "ferraris.tlog"


def one_line_err(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err, err
    return err


@pytest.mark.parametrize("argv, what", [
    (["log", str(SAMPLE), "--param-file", "/proc/x.param"], "parameter file"),
    (["log", str(SAMPLE), "--json", "/proc/x.json"], "JSON file"),
    (["log", str(SAMPLE), "--report", "/proc/r"], "the report"),
    (["gap", str(SAMPLE), "--report", "/proc/r"], "the report"),
    (["gap", str(SAMPLE), "--write-twin", "/proc/t.json"], "twin file"),
    (["tcal", str(SAMPLE), "--report", "/proc/r"], "the report"),
    (["tcal", str(SAMPLE), "--param-file", "/proc/x.param"], "parameter file"),
])
def test_an_unwritable_output_is_refused_before_any_work(capsys, argv, what):
    """/proc passes a permission check for root but creates nothing: tried, refused at once."""
    start = time.monotonic()
    assert main(argv) == 2
    line = one_line_err(capsys)
    assert f"cannot write {what}" in line and "before any work" in line, line
    assert time.monotonic() - start < 5, "refused only after the work"


def test_the_output_check_leaves_nothing_behind(tmp_path, capsys):
    """The check creates and removes a probe; a refused run writes nothing at all."""
    json_out = tmp_path / "out.json"
    assert main(["log", str(SAMPLE), "--json", str(json_out), "--param-file",
                 "/proc/x.param"]) == 2
    assert not json_out.exists()


def test_a_sub_commands_errors_point_to_its_own_help(capsys):
    for argv, own in ((["gap", "--no-such-option"], "see apmcal gap --help"),
                      (["log"], "see apmcal log --help")):
        with pytest.raises(SystemExit) as done:
            main(argv)
        assert done.value.code == 2
        assert own in one_line_err(capsys)


def test_every_argument_has_help():
    parser = build_parser()
    for name, sub in parser.subcommands.items():
        for action in sub._actions:
            assert action.help, f"apmcal {name}: {action.dest} has no help"
        assert "``" not in sub.format_help() and ":mod:" not in sub.format_help()
    assert "``" not in parser.format_help()


def test_an_unresolvable_host_is_said_at_once(capsys):
    start = time.monotonic()
    assert main(["live", "udp:no-such-host.invalid:14550"]) == 2
    assert "cannot resolve host" in one_line_err(capsys)
    assert time.monotonic() - start < 5


@pytest.mark.parametrize("content", [b"\x00", b"x", b"hello world, not a log\n"])
def test_a_file_that_is_no_log_is_called_that(tmp_path, capsys, content):
    path = tmp_path / "tiny.bin"
    path.write_bytes(content)
    assert main(["log", str(path)]) == 2
    line = one_line_err(capsys)
    assert "not a recognised log format" in line and "CSV layout" not in line, line


def test_qgc_params_written_and_every_format_read(tmp_path):
    values = {"INS_ACCOFFS_X": 0.25, "COMPASS_OFS_Y": -92.5}
    qgc = tmp_path / "cal.params"
    write_param_file(qgc, values, "test", fmt="qgc")
    lines = [ln for ln in qgc.read_text().splitlines() if not ln.startswith("#")]
    assert lines == ["1\t1\tCOMPASS_OFS_Y\t-92.5\t9", "1\t1\tINS_ACCOFFS_X\t0.25\t9"]
    assert read_param_file(qgc) == values
    mission_planner = tmp_path / "mp.param"
    mission_planner.write_text("INS_ACCOFFS_X,0.25\nCOMPASS_OFS_Y,-92.5\n")
    assert read_param_file(mission_planner) == values


def test_log_writes_qgc_params(tmp_path, capsys):
    out = tmp_path / "cal.params"
    assert main(["log", str(SAMPLE), "--param-file", str(out), "--param-format", "qgc",
                 "--quiet"]) == 0
    assert "INS_ACCOFFS_X" in read_param_file(out)
    assert "\t9" in out.read_text()


def test_the_heartbeat_wait_is_announced():
    """The wait for a vehicle is said before it starts, with the link and how long."""
    from apmcal.core.errors import ApmcalError
    from apmcal.link.connection import Connection

    said = []
    with pytest.raises(ApmcalError, match="no autopilot HEARTBEAT"):
        Connection("udpin:127.0.0.1:0", timeout_s=0.3, announce=said.append)
    assert said == ["waiting for a heartbeat from udpin:127.0.0.1:0 (0.3 s) …"]
