"""The window at process start in which a SIGINT still prints a traceback from ``bar-deploy``.

    python bench/early_sigint.py [--entry bar_policy.entry:deploy] [--step-ms 5] [--max-ms 200] [--reps 3]

Starts ``bar-deploy --help``'s work as the console script does (a wrapper that imports the entry point and
calls it; here with ``--policy`` of a missing file, so the run ends right after the imports), sends SIGINT
``d`` ms after ``Popen`` for d = 0, step, 2 step, ... and reports, per delay, how many of ``--reps`` runs
printed a traceback. The window is the largest delay with a traceback. ``--entry
bar_policy.deploy.cli:main`` measures the entry point before the early handling.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
WRAPPER = """import re
import sys
from {module} import {func}
if __name__ == "__main__":
    sys.argv[0] = re.sub(r"(-script\\.pyw|\\.exe)?$", "", sys.argv[0])
    sys.exit({func}())
"""


def one(entry: str, delay_s: float) -> bool:
    """True when a SIGINT ``delay_s`` after the start printed a traceback."""
    module, func = entry.split(":")
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    proc = subprocess.Popen(
        [sys.executable, "-c", WRAPPER.format(module=module, func=func), "--policy", "/nonexistent.onnx"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    time.sleep(delay_s)
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    return "Traceback" in err


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--entry", default="bar_policy.entry:deploy")
    p.add_argument("--step-ms", type=float, default=5.0)
    p.add_argument("--max-ms", type=float, default=200.0)
    p.add_argument("--reps", type=int, default=3)
    args = p.parse_args()
    window = 0.0
    d = 0.0
    while d <= args.max_ms + 1e-9:
        n = sum(one(args.entry, d / 1e3) for _ in range(args.reps))
        print(f"SIGINT at {d:6.1f} ms: traceback in {n} of {args.reps}")
        if n:
            window = d
        d += args.step_ms
    print(f"{args.entry}: a traceback up to {window:g} ms after the process started")


if __name__ == "__main__":
    main()
