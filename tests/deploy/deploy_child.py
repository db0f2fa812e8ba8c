"""``bar-deploy`` in a child process that records every CAN frame on python-can's ``virtual`` channels.

python-can's ``virtual`` interface delivers each frame to every other bus open on the same channel in the
process, so buses opened here before ``bar-deploy`` starts see the host's frames and the emulator's
replies. Usage (tests/deploy/test_deploy_stop.py)::

    python deploy_child.py FRAMES.json CHANNELS -- BAR_DEPLOY_ARGS...

writes ``[[channel, arbitration_id, data_hex, timestamp], ...]`` in arrival order per channel to FRAMES.json
when ``bar-deploy`` returns, and exits with its status.
"""

from __future__ import annotations

import json
import sys
import threading

import can

from bar_policy.deploy.cli import main


def _record(bus: can.BusABC, channel: str, out: list, done: threading.Event) -> None:
    while True:
        msg = bus.recv(timeout=0.05)
        if msg is not None:
            out.append([channel, msg.arbitration_id, bytes(msg.data).hex(), msg.timestamp])
        elif done.is_set():
            return  # nothing left queued after bar-deploy returned


def run(frames_path: str, channels: list[str], argv: list[str]) -> int:
    """Record the channels while ``bar-deploy argv`` runs; returns its exit status."""
    frames: dict[str, list] = {ch: [] for ch in channels}
    done = threading.Event()
    buses = [can.Bus(interface="virtual", channel=ch) for ch in channels]
    threads = [
        threading.Thread(target=_record, args=(b, ch, frames[ch], done), daemon=True)
        for b, ch in zip(buses, channels, strict=True)
    ]
    for t in threads:
        t.start()
    try:
        return main(argv)
    finally:
        done.set()
        for t in threads:
            t.join(timeout=5)
        for b in buses:
            b.shutdown()
        with open(frames_path, "w") as f:
            json.dump([rec for ch in channels for rec in frames[ch]], f)


if __name__ == "__main__":
    sep = sys.argv.index("--")
    sys.exit(run(sys.argv[1], sys.argv[2].split(","), sys.argv[sep + 1 :]))
