"""Simulated agents: the *other* of chapter 3 and the *learners* of chapters 4-6, and their store.
Imports ``coaching`` (a learner's adverb and effort), ``estimation``, ``bodies``, ``motion``, ``io``."""
