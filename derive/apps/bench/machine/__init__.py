"""What this machine allows, measured in the same run: operation latencies (probe, compiled
by c_kernels), scalar throughput (scalar_throughput), a case's latency bound (bound) and the
generated Python's floor (python_floor)."""
