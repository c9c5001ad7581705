"""Reporting a run: statistics, tables, the comparison of planners, figures, the report (Markdown and
HTML), merged runs and exports to other tools. Reads what :mod:`fixbench.bench.running` stored;
imports nothing from :mod:`fixbench.bench.analysis`."""
