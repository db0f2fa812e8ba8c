"""``bar-bus`` against the emulator: discover, param read/write, calibrate."""

from __future__ import annotations

import numpy as np

from bar_policy.robstride.calibration import Calibration
from bar_policy.robstride.tools import main, model_guess

from .conftest import swept_emulator


def test_model_guess():
    assert model_guess(14.0) == "rs-00"
    assert model_guess(17.0) == "rs-01/rs-02"
    assert model_guess(5.5) == "rs-05"
    assert model_guess(4.0).startswith("?")


def test_discover_lists_ids_models_and_status(channels, make_emulator, capsys, listeners):
    emu = make_emulator(extra_ids={"can0": [3]})
    emu.inject("left_wrist_roll", fault_word=1 << 2)  # faultSta reads 0x00000004 (undervoltage)
    argv = ["discover", "--can-interface", "virtual", "--channel", channels["can0"], "--scan-to", "32"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "8 device(s) answered ids 1..32" in out
    rows = {int(line.split()[0]): line for line in out.splitlines()[2:]}
    assert sorted(rows) == [3, 11, 12, 13, 14, 15, 16, 17]
    assert "rs-01/rs-02" in rows[11] and "rs-00" in rows[12] and "rs-05" in rows[15]
    assert "0x00000004" in rows[16] and "0x00000000" in rows[15]
    # read-only: no stop, enable, MIT or write frames went out
    assert listeners["can0"].host_frames((1, 3, 4, 6, 18)) == []
    argv = ["discover", "--can-interface", "virtual", "--channel", channels["can0"], "--scan-to", "16"]
    assert main([*argv, "--status"]) == 0
    out = capsys.readouterr().out
    assert "mode=reset faults=no faults" in out


def test_param_write_then_read(channels, make_emulator, capsys):
    emu = make_emulator()
    base = ["--can-interface", "virtual", "--channel", channels["can0"], "--id", "12", "--index", "0x700B"]
    assert main(["param", "write", *base, "--value", "12.5"]) == 0
    assert emu.motor(12).params[0x700B] == 12.5
    assert main(["param", "read", *base]) == 0
    assert "parameter 0x700b (limit_torque) = 12.5" in capsys.readouterr().out
    # an unknown index reads as a motor refusal (status byte), reported as an error
    assert main(["param", "read", *base[:-1], "0x1234", "--type", "f32"]) == 1


def test_calibrate_records_true_offsets(tmp_path, robot, channels, make_emulator, capsys):
    out = tmp_path / "cal.json"
    with swept_emulator(robot, make_emulator, seed=5) as (emu, true_offsets):
        code = main(
            [
                "calibrate",
                "--can-interface",
                "virtual",
                "--channels",
                f"{channels['can0']},{channels['can1']}",
                "--calibration",
                str(out),
                "--duration",
                "1.0",
                "--rate",
                "200",
            ]
        )
    assert code == 0
    got = Calibration.load(out).offsets(robot)
    # both stops were sampled exactly: the offsets are right within the 16-bit position step
    np.testing.assert_allclose(got, true_offsets, atol=2 * 8 * np.pi / 65535)
    assert "Wrote calibration" in capsys.readouterr().out
    assert not any(emu.enabled().values())
