"""Coaching with emphatic motions and adverbs (thesis ch. 4-6)."""
