"""Coaching with emphatic motions and adverbs (thesis ch. 4-6): sessions and trials, policies,
feasibility of a demonstration, body-part and sub-goal emphasis, effort. Imports ``pss``,
``estimation``, ``bodies``, ``motion``; never the bus."""
