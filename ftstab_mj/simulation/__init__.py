"""Layer 4, simulation: a plant under its laws, sample by sample.

``run_loop`` (the run loop: MuJoCo's control callback, batches of samples, a status at the end),
``stages`` (sensor, differentiator, actuator between plant and law), ``native`` (the C twin of the
per-sample work), ``ideal_chain`` (the exact reference simulation of the chain), ``records`` (what a
run produces: the contract between the run loop, the log sinks and the metrics) and
``interrupts`` (Ctrl-C and signals: a run that stops leaves consistent logs). May import: config,
control, plants.
"""
