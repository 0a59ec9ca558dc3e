"""The catalog filters whose derived float32 bound is 1 or more although their float32 code
is accurate: the bound's growth term G sums ||A_k ... A_{k-j+1}||_inf over the whole run
(derive.apps.float_tolerance), and the 24-state flight-controller models carry states
that their sensors observe weakly (the earth field, the body magnetic bias, the wind), so
their closed-loop maps barely contract and G reaches ~1.7e4 over verify's 1000 steps
(bound ~10, measured error ~1.4e-5). An open defect of the bound, not of the code: the
tests hold these filters to sqrt(u32) instead, and this list exactly, so that a bound
that becomes meaningful (or a new model whose bound is not) shows."""

LOOSE_FLOAT_BOUNDS = frozenset({("ins_fc24", "ekf"), ("ins_fc24_eskf", "eskf")})
