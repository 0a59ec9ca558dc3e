"""The generator's own costs: generation time of large models (generation_scaling), the
latency schedule's and bounds' time (schedule_scaling), files that compile in seconds
(compile_size), the command line's start-up (startup), each child measured by child_usage."""
