"""Layer 8, studies: many runs and what they say together.

``sweep`` (grids and seeded draws over a base scenario, on serial, process-pool or Dask engines,
journaled and resumable), ``compare`` (several laws on one base scenario), ``montecarlo`` (Theorem
1's time bound on many initial states) and ``batch_env`` (the environment of processes that run
many simulations). May import: every layer below (config .. scenario).
"""
