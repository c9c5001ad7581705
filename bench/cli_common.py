"""What every fixbench command line shares: strict JSON output and one way to run a click command.

:mod:`fixbench.bench.cli` (the ``fixbench`` command), :mod:`fixbench.bench.references` and the
repository's studies (``studies/``, not installed) run their click commands through :func:`run_command`,
so a user error reads the same everywhere. This module imports no other module of fixbench.bench, so
that any of them can import it.
"""

from __future__ import annotations

import json

import click
import numpy as np

from fixbench.cases.errors import FixbenchError
from fixbench.cases.files import strict_value


def echo_json(obj) -> None:
    """Print strict JSON (RFC 8259: no NaN or Infinity; missing numbers are null)."""
    click.echo(json.dumps(strict_value(obj), indent=1, allow_nan=False))


def run_command(command: click.Command, argv: list[str] | None, prog_name: str) -> int:
    """Run a click ``command`` on ``argv`` (default: ``sys.argv[1:]``) as fixbench runs every command
    line: user errors (bad options, bad case or matrix files, numerical trouble, file-system faults)
    become one line on stderr and exit code 2, Ctrl-C exit code 130; returns the exit code."""
    try:
        rv = command.main(args=argv, prog_name=prog_name, standalone_mode=False)
        if isinstance(rv, int) and not isinstance(rv, bool):  # click returns an Exit's code here
            return rv
    except click.exceptions.Exit as exc:
        return exc.exit_code
    except click.Abort:
        click.echo("fixbench: aborted", err=True)
        return 130
    except click.ClickException as exc:
        click.echo(f"fixbench: {exc.format_message()}", err=True)
        return 2
    except FixbenchError as exc:
        click.echo(f"fixbench: {exc}", err=True)
        return 2
    except np.linalg.LinAlgError as exc:
        click.echo(f"fixbench: numerical error: {exc}", err=True)
        return 2
    except OSError as exc:  # permission, no space, read-only file system: one line, nothing half-written
        where = f"{exc.filename}: " if exc.filename else ""
        click.echo(f"fixbench: {where}{exc.strerror or exc}", err=True)
        return 2
    return 0
