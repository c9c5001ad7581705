"""A run's records: the row schema and every key that groups rows (:mod:`.rows`), the run directory's
store (:mod:`.store`) and the held-out split (:mod:`.keys`). The lowest room of the harness: every other
room reads and writes rows through it, and it imports none of them.
"""
