"""docs/library.md's examples run as they stand, from the repository's folder, and say what the
page says they say."""
import os
import re
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "library.md"


def blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", PAGE.read_text(), re.S)


def run(code: str, tmp_path, capsys) -> tuple[dict, str]:
    namespace: dict = {}
    cwd = os.getcwd()
    try:
        os.chdir(tmp_path)
        (tmp_path / "logs").symlink_to(ROOT / "logs")
        exec(compile(code, str(PAGE), "exec"), namespace)
    finally:
        os.chdir(cwd)
    return namespace, capsys.readouterr().out


def test_the_example_calibrates_the_sample_and_writes_its_files(tmp_path, capsys):
    example, errors = blocks()
    ns, out = run(example, tmp_path, capsys)
    assert "verdict:" in out and ns["result"].calibration.method == "ferraris"
    # the offsets lie within a few σ of the simulator's injected truth (independent truth)
    assert np.all(np.abs(ns["z"]) < 4), ns["z"]
    assert (tmp_path / "ferraris-calibration.json").exists()
    assert (tmp_path / "ferraris.param").read_text().count("INS_ACCOFFS_") == 3
    saved = ns["again"].sensors["acc"]
    np.testing.assert_allclose(saved.offset, ns["acc"].offset)


def test_the_error_example_prints_one_line(tmp_path, capsys):
    _, errors = blocks()
    _, out = run(errors, tmp_path, capsys)
    assert out.count("\n") == 1 and "no-such-file.tlog" in out
