"""Regret references, one package, one module a step. A reference is the best layout known for every
position of a problem, with a certified lower bound where one is known; regret is measured against it.

- **format**: the shipped reference files and their checks are :mod:`fixbench.cases.references` (the
  problem's own package: the catalog ships them, and the oracle's and the parts' checks read them).
- **prove** (:mod:`.prove`): the reference of a run's problem, ``exact``'s optimum where it can be had
  (position by position in ``fixbench run``'s proof phase), else the shipped one restricted to the
  problem's tasks. ``fixbench run`` calls this step and :mod:`.score`, nothing else.
- **score** / **rescore** (:mod:`.score`): a row's regret against its reference; a run's rows scored
  again against the references as they are now (``fixbench references rescore DIR``).
- **build** (:mod:`.build`): the reference portfolio, written as the catalog's shipped reference
  (``fixbench references build CASE``; ``fixbench references check`` on the small cases).
- **bound** (:mod:`.bound`, with :mod:`.compliance_bound` and :mod:`.zone_bound`): certified lower
  bounds written into a shipped reference (``fixbench references bound CASE``).
- **update** (:mod:`.update`): the loop. ``fixbench references update RUN_DIR [DIR ...]`` takes every
  layout of a run that beats a shipped reference into the catalog, then rescores RUN_DIR and each DIR.

The package sits below :mod:`fixbench.bench.running` and above :mod:`fixbench.bench.records` (the rows
and their store), and imports nothing from the other rooms.
"""
