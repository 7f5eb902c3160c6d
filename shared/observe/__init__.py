"""Observability: the rerun dashboard fed by the cluster's events (``dashboard``: what is logged;
``layout``: its tabs and views; ``labels``: labels that never overlap; ``latency``: the requests'
table; only the observer imports them) and the real viewer driven headless for screenshots
(``viewer``). Imports ``motion`` and ``errors``."""
