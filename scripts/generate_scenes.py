#!/usr/bin/env python3
"""Regenerate the rooms shipped in ``scenes/`` (one per generator kind, fixed seed).

Rerunning reproduces the files byte for byte (tests/test_generator.py checks it). Usage::

    python3 scripts/generate_scenes.py [--out scenes] [--seed 2024]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from simulator.generator import ROOM_KINDS, GeneratorConfig, generate_room  # noqa: E402

SHIPPED_SEED = 2024
"""The seed of the shipped rooms."""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=REPO / "scenes", help="parent folder of the rooms")
    parser.add_argument("--seed", type=int, default=SHIPPED_SEED, help="generator seed")
    parser.add_argument("--kind", choices=ROOM_KINDS, action="append", help="only these kinds (repeatable)")
    args = parser.parse_args(argv)
    for kind in args.kind or ROOM_KINDS:
        path = generate_room(kind, args.out / kind, args.seed, GeneratorConfig())
        size = sum(p.stat().st_size for p in path.parent.rglob("*") if p.is_file())
        print(f"{kind:13s} {path}  {size / 1e6:.2f} MB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
