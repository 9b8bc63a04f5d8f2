#!/usr/bin/env python
"""A rig.yaml from a Kalibr calibration (issue 15; ``ampc_vo.io.kalibr``).

    python scripts/rig_from_kalibr.py CAMCHAIN.yaml --layout LAYOUT.yaml --out rig.yaml

CAMCHAIN is Kalibr's ``camchain.yaml`` (pinhole-radtan or pinhole-equi cameras and the chain
T_cn_cnm1), calibrated with the trailer standing straight (hitch angle 0). LAYOUT names each
camchain camera (name, body, topic) and gives the measured pose of one reference camera in the
vehicle frame, the hitch position, hitch_height and each body's axle_x (format: the docstring of
ampc_vo/io/kalibr.py).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing

from ampc_vo.tools.cli import exit_codes  # noqa: E402


@exit_codes
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("camchain", type=Path, help="Kalibr camchain.yaml")
    parser.add_argument("--layout", type=Path, required=True, help="layout YAML: camera names, bodies, topics, reference pose, hitch, axles")
    parser.add_argument("--out", type=Path, required=True, help="rig.yaml to write")
    args = parser.parse_args(argv)
    from ampc_vo.io.kalibr import load_rig_from_kalibr
    from ampc_vo.rig import save_rig

    rig = load_rig_from_kalibr(args.camchain, args.layout)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save_rig(rig, args.out)
    print(f"{args.out}: {len(rig.cameras)} cameras ({', '.join(f'{c.name} on {c.body}' for c in rig.cameras)})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
