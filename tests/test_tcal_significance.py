"""`apmcal tcal` never enables a calibration it cannot show: without a significant drift
coefficient nothing is proposed; the bundled warm-up sample's drift is found and enabled."""
import json
from pathlib import Path

import numpy as np

from apmcal.ardupilot.paramfile import read_param_file
from apmcal.cli import main

ROOT = Path(__file__).resolve().parents[1]


def test_ferraris_session_enables_nothing(tmp_path, capsys):
    """ferraris.tlog spans 10 °C with c1 smaller than its own σ: no INS_TCAL1_ENABLE 1."""
    out, js = tmp_path / "t.param", tmp_path / "t.json"
    assert main(["tcal", str(ROOT / "logs" / "ferraris.tlog"), "--param-file", str(out),
                 "--json", str(js)]) == 0
    assert read_param_file(out) == {}
    assert "not proposed" in out.read_text() and "within 2σ" in out.read_text()
    result = json.loads(js.read_text())
    assert result["params"] == {} and result["tcal"][0]["significant"] is False
    assert "nothing proposed" in capsys.readouterr().out


def test_bundled_warmup_sample_is_enabled_and_matches_its_truth(tmp_path):
    """The README's recipe: logs/warmup.bin gives INS_TCAL1_ENABLE 1 and c1 within 3σ of the
    injected drift (logs/warmup.truth.json)."""
    out, js = tmp_path / "t.param", tmp_path / "t.json"
    assert main(["tcal", str(ROOT / "logs" / "warmup.bin"), "--param-file", str(out),
                 "--json", str(js), "--quiet"]) == 0
    assert read_param_file(out)["INS_TCAL1_ENABLE"] == 1
    fit = json.loads(js.read_text())["tcal"][0]
    temp = json.loads((ROOT / "logs" / "warmup.truth.json").read_text())["effects"]["temperature"]
    for sensor, key in (("acc", "acc_coef"), ("gyr", "gyro_coef")):
        c1 = np.array(fit[sensor]["c1_c2_c3_xyz"])[0]
        s1 = np.array(fit[sensor]["sigma"])[0]
        assert np.all(np.abs(c1 - np.array(temp[key]) * 1e6) <= 3 * s1), (sensor, c1, s1)
