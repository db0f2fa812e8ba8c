"""``python -m bar_policy.obs [--json NAME] [--write-golden]``: print the shipped layouts' fingerprints."""

from __future__ import annotations

import argparse
import sys
from importlib import resources
from pathlib import Path

from bar_policy.obs.manager import SHIPPED_LAYOUTS, ObservationManager, shipped_managers


def main(argv: list[str] | None = None) -> int:
    """Print ``name version size fingerprint golden-status`` per shipped layout."""
    p = argparse.ArgumentParser(prog="python -m bar_policy.obs", description=__doc__)
    p.add_argument("--json", metavar="NAME", choices=sorted(SHIPPED_LAYOUTS), help="print a layout's JSON")
    p.add_argument(
        "--write-golden",
        action="store_true",
        help="overwrite the golden files with the code's layouts (a deliberate schema change)",
    )
    args = p.parse_args(argv)
    managers = shipped_managers()
    if args.json:
        print(managers[args.json].to_json())
        return 0
    folder = Path(str(resources.files("bar_policy.obs").joinpath("schemas")))
    for name, om in managers.items():
        if args.write_golden:
            (folder / f"{name}.json").write_text(om.to_json() + "\n")
        try:
            golden = ObservationManager.golden(name).fingerprint
            status = "matches golden" if golden == om.fingerprint else f"DRIFT (golden {golden})"
        except (OSError, ValueError) as e:
            status = f"no valid golden file ({e})"
        print(f"{name}  v{om.schema.version}  size={om.size}  fingerprint={om.fingerprint}  {status}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
