"""``derive bench``: per-step time of derive's generated filters against their peers,
and batch throughput over many tracks, measured in one run.

Grouped by what is measured: ``peers`` (the same filters elsewhere), ``throughput`` (many
tracks, one thread and every core), ``machine`` (this machine's latencies, throughput and
the bounds they set), ``costs`` (the generator's own: generation, compilation, start-up).
Beside them: timing (median of repeats), cases (what is timed, the implementation
protocol), generated (derive's C and Python), run (the whole bench and its table).
"""
