"""Layer 9, figures: pictures of runs and studies (matplotlib, imported only when drawing).

``run_report`` (``ftstab report``: the figures of one run from its log) and ``sweep_report`` (a
sweep's plots and log-log fits), ``compare_report`` (``ftstab compare``'s figures: small multiples, slopes
only through power laws). May import: every layer below, studies included (a sweep's file and table).
"""
