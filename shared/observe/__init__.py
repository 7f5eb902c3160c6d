"""Observability: the rerun dashboard fed by the cluster's events (only the observer imports it)
and the real viewer driven headless for screenshots. Imports ``motion`` and ``errors``."""
