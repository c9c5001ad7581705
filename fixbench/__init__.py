"""fixbench: an optimisation benchmark for multi-robot fixture planning on validated plate FEA.

One import name for the whole library; the repository keeps its three folders, mapped here by the
build (``pyproject.toml``, ``[tool.setuptools.package-dir]``):

- :mod:`fixbench.cases` (folder ``cases/``): the problem: geometry, materials, plate FEA, the
  counted deformation oracle, the case catalog, the PettingZoo environment;
- :mod:`fixbench.solvers` (folder ``solvers/``): the planners behind one interface and a registry;
- :mod:`fixbench.bench` (folder ``bench/``): the harness: matrices, executors, results, reports, CLI.

Nothing heavy is imported here, so that ``fixbench --help`` starts fast.
"""

__version__ = "0.1.0"
