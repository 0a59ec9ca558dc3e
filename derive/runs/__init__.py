"""What a generated run does, in no language: the unit of generation (one model, one
filter) and the description of each kind of run loop (:mod:`derive.runs.unit`)."""
