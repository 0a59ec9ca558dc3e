"""Throughput over many tracks: one machine thread (batch) and every core, threads and Dask
(scaling)."""
