"""``python -m fixbench``: the same command line as the ``fixbench`` script."""

from fixbench.bench.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
