import os
import signal
import threading

import pytest

from bar_policy.signals import STOP_SIGNALS, StopSignals


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_each_stop_signal_sets_the_same_flag(sig):
    before = signal.getsignal(sig)
    with StopSignals() as stop:
        assert stop.installed and not stop.requested
        os.kill(os.getpid(), sig)
        assert stop.requested
        assert stop.signal_name == sig.name
        assert stop.reason == f"{sig.name} received"
    # handlers restored on exit
    assert signal.getsignal(sig) == before


def test_second_signal_is_counted_not_raised():
    with StopSignals() as stop:
        os.kill(os.getpid(), signal.SIGTERM)
        os.kill(os.getpid(), signal.SIGINT)  # would be KeyboardInterrupt without the handler
        os.kill(os.getpid(), signal.SIGHUP)
        assert stop.count == 3
        assert stop.signal_name == "SIGTERM"  # the first one names the reason


def test_request_without_signal_and_off_main_thread():
    out = {}

    def worker():
        with StopSignals() as stop:
            out["installed"] = stop.installed
            stop.request("test")
            stop.request("later")
            out["reason"] = stop.reason

    t = threading.Thread(target=worker)
    t.start()
    t.join()
    assert out == {"installed": False, "reason": "test"}
    assert set(STOP_SIGNALS) == {signal.SIGINT, signal.SIGTERM, signal.SIGHUP}
