"""Reruns of the thesis's experiments on the cluster, written up as reports (`mirrorcoach reproduce`)."""
