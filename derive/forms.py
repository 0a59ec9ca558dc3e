"""The forms of a filter's derivation that a model may declare and a filter option may
override: shared by the model (:mod:`derive.model`) and the options (:mod:`derive.options`),
so that neither imports the other."""

ROW_FORMS = ("scalar", "vector")
"""How a filter derives its dense covariance work (option ``rows``, ``NonlinearModel(rows=)``):
entry by entry, or as vector rows (derive.filters.vector_rows)."""

UPDATE_FORMS = ("batch", "sequential")
"""How a sensor's update fuses its measurements (option ``update``): all at once through
the LDL^T factorisation of S, or one scalar at a time (R diagonal or constant)."""
