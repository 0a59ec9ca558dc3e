"""The applications: what uses the generator to do a job.

``verify`` (generated code against the NumPy reference), ``paper`` (the papers' own forms,
for the burden audit), ``audit`` and ``formulas`` (the papers' operation counts),
``checks`` (the papers' equivalence claims), ``simulate`` (simulated runs), ``latency``
(the run loop's latency bound), ``casadi_bridge`` (Jacobians cross-checked by automatic
differentiation), and the packages ``report``, ``bench`` and ``gnss``. They reach the
generator through derive.pipeline (render, write, load) and the public modules of
``derive``; nothing in the generator imports them.
"""
