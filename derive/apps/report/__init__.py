"""The report of ``derive reproduce``: one module per part of the papers, a document model
rendered to Markdown and HTML, and the job that runs them (:func:`derive.apps.report.job.run`).

Modules: job (the stages, progress bar, summary), context (what stages share), generation
(regenerate, compile, verify), tracking (MPT3D, GSM2D), sspred, mdkf, gnss, navigation
(the INS/GNSS EKF of docs/navigation.md), burden,
figures (matplotlib, Agg), document and page (index.md, index.html, results.md),
provenance (date, versions, machine, command: the footer and ``derive --version``).
"""
