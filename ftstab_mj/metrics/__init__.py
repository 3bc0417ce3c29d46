"""Layer 5, metrics: what a run measured, computed from its logged arrays only (the same code live and on replay).

``run_metrics`` (settling, accuracy, effort, chattering, Theorem 1 and 3 checks), ``expectations``
(pinned metrics with tolerances, ``ftstab check``) and ``certificate_cache`` (a loop's certificate,
computed once per parameter set, in the process and on disk). May import: config, control,
plants, simulation (its records).
"""
