"""`scripts/check_device.py` runs its checks (on the CPU here, CUDA where present) and passes."""

import check_device


def test_the_device_check_passes_on_this_machine(capsys):
    assert check_device.main(["--device", "cpu"]) == 0
    out = capsys.readouterr().out
    assert out.count("ok  ") == 6 and "FAIL" not in out
