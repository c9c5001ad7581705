"""Analyses beside the benchmark: person-by-person optima of the small cases (equilibria), how many
robots a job needs, the oracle's speed (`fixbench perf`) and their figures. Nothing here is a
benchmark result; it may use both other rooms."""
