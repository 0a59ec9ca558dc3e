"""Peers of derive's generated filters, timed on the same cases: derive's NumPy reference,
FilterPy and pykalman (libraries), CasADi's generated C (casadi_c), SymForce's C++
(symforce_peer) and the INS/GNSS EKF against all of them (navigation)."""
