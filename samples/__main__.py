"""``python -m samples [NAME ...]``: tabulate sample materials (cached) and print their paths.

Names: the analytic catalogue (``ggx_glossy``, ...) and the measured materials
``rgl/NAME`` and ``nielsen/NAME`` (decoded from Neural-BRDF networks); ``--list`` shows all.
"""

import argparse
import sys

from . import CATALOG, DEFAULT, measured_names, sample_path

parser = argparse.ArgumentParser(
    prog="python -m samples", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
)
parser.add_argument(
    "names",
    nargs="*",
    help=f"sample names (default {DEFAULT}); 'all' for every analytic "
    "one, 'measured' for every measured one (59 tables of 35 MB: about 2 GB of cache)",
)
parser.add_argument("--list", action="store_true", help="list the catalogue (analytic, then measured)")
parser.add_argument("--force", action="store_true", help="re-tabulate even if cached")
args = parser.parse_args()
measured = measured_names()
if args.list:
    for name, model in CATALOG.items():
        print(f"{name:12s} {model}")
    for name in measured:
        print(f"{name:34s} measured (Neural-BRDF, Sztrajman et al. 2021)")
    sys.exit(0)
names = []
for n in args.names or [DEFAULT]:
    names += list(CATALOG) if n == "all" else measured if n == "measured" else [n]
unknown = [n for n in names if n not in CATALOG and n not in measured]
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
