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
