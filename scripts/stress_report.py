"""Run the stress suite (``pytest -m stress``) and write its case counts into STRESS.md.

    .venv/bin/python scripts/stress_report.py [extra pytest args]

The suite records every case's outcome (tests/_stress.py); this script runs it with
BRDF_MOMENTS_STRESS_SUMMARY set, times it, and replaces the table between the markers in
STRESS.md. The rest of STRESS.md is prose kept by hand.
"""

from __future__ import annotations

import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BEGIN, END = "<!-- stress-table:begin -->", "<!-- stress-table:end -->"


def render(summary: dict, seconds: float, result: str) -> str:
    lines = [
        f"Run: {datetime.date.today().isoformat()}, `pytest -m stress` ({result}), wall time "
        f"{seconds:.0f} s on {platform.machine()} with {os.cpu_count()} cores (shared).",
        "",
        "| category | cases | clear error | clamped / flagged valid | valid (checked) |",
        "|---|---:|---:|---:|---:|",
    ]
    totals = [0, 0, 0, 0]
    for cat, data in summary.items():
        c = data["counts"]
        row = [c.get("error", 0), c.get("clamped", 0), c.get("valid", 0)]
        n = sum(row)
        totals = [t + v for t, v in zip(totals, [n] + row)]
        lines.append(f"| {cat} | {n} | {row[0]} | {row[1]} | {row[2]} |")
    lines.append(f"| **total** | **{totals[0]}** | **{totals[1]}** | **{totals[2]}** | **{totals[3]}** |")
    return "\n".join(lines)


def main(argv):
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "summary.json")
        env = dict(os.environ, BRDF_MOMENTS_STRESS_SUMMARY=out)
        env.setdefault("BRDF_MOMENTS_CACHE", os.path.join(ROOT, ".cache", "engine"))
        t = time.perf_counter()
        res = subprocess.run(
            [sys.executable, "-m", "pytest", "-q", "-m", "stress", "tests", *argv],
            cwd=ROOT,
            env=env,
            capture_output=True,
            text=True,
        )
        seconds = time.perf_counter() - t
        last = (res.stdout.strip().splitlines() or ["no output"])[-1].strip("= ")
        print(res.stdout[-3000:])
        if not os.path.exists(out):
            print(res.stderr[-3000:], file=sys.stderr)
            return 1
        with open(out) as fh:
            summary = json.load(fh)
    table = render(summary, seconds, last)
    path = os.path.join(ROOT, "STRESS.md")
    with open(path, encoding="utf-8") as fh:
        text = fh.read()
    if BEGIN not in text or END not in text:
        print(f"{path}: markers {BEGIN} / {END} not found", file=sys.stderr)
        return 1
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(f"{head}{BEGIN}\n{table}\n{END}{tail}")
    with open(
        os.path.join(ROOT, "out", "stress-summary.json") if os.path.isdir(os.path.join(ROOT, "out")) else os.devnull,
        "w",
    ) as fh:
        json.dump(summary, fh, indent=1)
    print(table)
    return res.returncode


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
