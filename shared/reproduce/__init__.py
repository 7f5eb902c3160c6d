"""Reruns of the thesis's experiments on the cluster (``ch3``, ``coaching``) and their reports
(``ch3_report``, ``coaching_report``, ``coaching_stats``, ``tidy``): ``mirrorcoach reproduce``.
Imports the bus's client and the library below it."""
