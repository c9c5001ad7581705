"""Start-up time of the everyday commands, as whole processes, side by side with a baseline.

    python -m studies.startup [--runs 7] [--baseline "python /old/checkout/fixbench-cli.py"] [--json]

Runs ``fixbench --help``, ``fixbench cases`` and ``fixbench solvers`` (through ``python -m
fixbench``) ``--runs`` times each, interleaved with the same commands through ``--baseline`` (any
command prefix: an older checkout, an installed copy) or, without one, with a bare interpreter
(``python -c pass``) as the floor. Prints per command the median wall time of each side and their
ratio. Interleaving keeps both sides under the same load; the medians, not the means, are compared.
Not a test: the figures go in closing notes and the README.
"""

from __future__ import annotations

import json
import shlex
import statistics
import subprocess
import sys
import time

import click

from fixbench.bench.cli_common import run_command

COMMANDS = (("--help",), ("cases",), ("solvers",))


def _wall(cmd: list[str]) -> float:
    t = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t


def measure(runs: int, baseline: list[str] | None) -> list[dict]:
    """Median wall time of each command and of its baseline, run alternately."""
    ours = [sys.executable, "-m", "fixbench"]
    out = []
    for args in COMMANDS:
        other = [*baseline, *args] if baseline else [sys.executable, "-c", "pass"]
        a, b = [], []
        for _ in range(runs):
            a.append(_wall([*ours, *args]))
            b.append(_wall(other))
        ma, mb = statistics.median(a), statistics.median(b)
        out.append({"command": "fixbench " + " ".join(args), "median_s": ma, "baseline": shlex.join(other),
                    "baseline_median_s": mb, "ratio": ma / mb})
    return out


PROG = "python -m studies.startup"


@click.command(help=__doc__.split("\n")[0], context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--runs", type=int, default=7, show_default=True)
@click.option("--baseline", help="Command prefix to compare with (default: a bare interpreter).")
@click.option("--json", "as_json", is_flag=True)
def cli(runs: int, baseline: str | None, as_json: bool) -> None:
    rows = measure(runs, shlex.split(baseline) if baseline else None)
    if as_json:
        print(json.dumps(rows, indent=1))
    else:
        for r in rows:
            print(f"{r['command']:>18}: {r['median_s']:.2f} s   baseline {r['baseline_median_s']:.2f} s   "
                  f"ratio {r['ratio']:.2f}   ({r['baseline']})")


def main(argv: list[str] | None = None) -> int:
    """Run the command line on ``argv`` (default: ``sys.argv[1:]``); returns the exit code (2: a usage error)."""
    return run_command(cli, argv, PROG)


if __name__ == "__main__":
    raise SystemExit(main())
