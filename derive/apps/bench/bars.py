"""The acceptance bars of ``derive bench``, one table.

Every number a measured value is held to (docs/performance.md, docs/navigation.md) is an
entry of :data:`BARS`, by name; each section of the bench (:mod:`.run`, :mod:`.peers`,
:mod:`.throughput`, :mod:`.costs`) reads its bars from here, and so do their tests.
The unit is in the name's comment: a ratio reached (at least), a share of a peer's (at
most), seconds or bytes (at most). :data:`REFERENCE` holds the measurements on the
machine where the time bars were set, through which the scaled bars restate them here.
"""

from __future__ import annotations

BARS: dict[str, float] = {
    # peers: derive's generated C KF of mpt3d_a per step, times faster than
    "kf_c_over_filterpy": 1000.0,
    "kf_c_over_casadi": 4.0,
    # throughput: the batch of generated C over simdkalman's, times; on both cores,
    # track-steps per second (at least)
    "batch_over_simdkalman": 50.0,
    "batch_both_cores": 6e8,
    # seconds per step, at most: the generated C KF mpt3d_a; the SSKF mpt3d_a (25 % over
    # two dependent fmas of 2.3 ns); the pure-Python KF mpt3d_b x 3 in one loop
    "kf_c_step": 10e-9,
    "sskf_c_step": 1.25 * 2.3e-9,
    "kf_python_step": 1.0e-6,
    # scaled (through REFERENCE): the Python KF's bar where it was set; the SSKF within
    # this many times two dependent fmas here
    "kf_python_step_scaled": 1.2e-6,
    "sskf_over_two_fmas": 1.25,
    # machine: the time per step (fastest repeat) within this many times its bound (its
    # chain's latency or its run's memory traffic, the larger); the latency schedule's
    # bound within this share of the default schedule's
    "kf_over_bound": 1.2,
    "sskf_over_bound": 1.5,
    "latency_schedule_share": 0.75,
    # costs: seconds of derive generate --all; of 120 axes for each of kf, lf, sskf; of
    # the dense 24-state KF, and its peak bytes
    "catalog_generation": 30.0,
    "axes_generation": 10.0,
    "dense_generation": 30.0,
    "dense_generation_bytes": float(1 << 30),
    # costs: a dense 24-state KF generated and compiled, seconds and peak bytes each; its
    # .c file's bytes (SymForce's generated step for the same model)
    "compile_seconds": 30.0,
    "compile_bytes": 1e9,
    "c_file_bytes": 2.5e6,
    # navigation (ins_gnss): seconds to generate the EKF's C; the C per call, times
    # faster than FilterPy's and CasADi's C
    "ins_gnss_generation": 2.0,
    "ins_over_filterpy": 300.0,
    "ins_over_casadi": 2.0,
    # navigation: SymForce's flops over derive's, per function, at least (this many flops
    # more than derive's, over derive's)
    "ins_flops_fewer": 1.0,
    # navigation against SymForce's C++: flops, x86-64 and Cortex-M4F code as a share
    # of SymForce's (at most); time per call as a share of SymForce's, per build; seconds
    # to generate ins_fc24's EKF
    "symforce_flops_share": 0.9,
    "symforce_code_share": 1.0,
    "symforce_time_double_O2": 0.8,
    "symforce_time_float_O2": 0.5,
    "symforce_time_double_native": 0.5,
    "symforce_time_float_native": 0.5,
    "ins_fc24_generation": 3.0,
}

#: Where the time bars were set: CasADi's C for the KF step of mpt3d_a, FilterPy's.
REFERENCE: dict[str, float] = {
    "casadi_kf_step": 48e-9,
    "filterpy_kf_step": 17e-6,
}
