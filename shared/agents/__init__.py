"""Simulated agents: the *other* of chapter 3 and the *learners* of chapters 4-6 (SPEC section 6)."""
