"""``derive bench``: per-step time of derive's generated filters against their peers,
and batch throughput over many tracks, measured in one run.

Modules: timing (median of repeats), cases (what is timed, the implementation protocol),
generated (derive's C and Python), peers (NumPy reference, FilterPy, pykalman),
casadi_c (CasADi's generated C), batch (track-steps per second), run (the whole bench and
its table).
"""
