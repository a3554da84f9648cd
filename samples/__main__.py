"""``python -m samples [NAME ...]``: tabulate sample materials (cached) and print their paths."""

import argparse
import sys

from . import CATALOG, DEFAULT, sample_path

parser = argparse.ArgumentParser(prog="python -m samples", description=__doc__)
parser.add_argument("names", nargs="*", help=f"sample names (default {DEFAULT}); 'all' for every one")
parser.add_argument("--list", action="store_true", help="list the catalogue")
parser.add_argument("--force", action="store_true", help="re-tabulate even if cached")
args = parser.parse_args()
if args.list:
    for name, model in CATALOG.items():
        print(f"{name:12s} {model}")
    sys.exit(0)
names = list(CATALOG) if args.names == ["all"] else (args.names or [DEFAULT])
unknown = [n for n in names if n not in CATALOG]
if unknown:
    print(f"error: unknown sample(s) {', '.join(unknown)}; try --list", file=sys.stderr)
    sys.exit(2)
try:
    for name in names:
        print(sample_path(name, force=args.force))
except (OSError, ValueError) as exc:  # a bad cache folder: one line, no traceback
    print(f"error: {exc}", file=sys.stderr)
    sys.exit(2)
except KeyboardInterrupt:
    print("interrupted: nothing left half-written", file=sys.stderr)
    sys.exit(130)
