"""Observability: the rerun dashboard fed by the cluster's events (only the observer imports it)."""
