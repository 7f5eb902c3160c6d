"""Chapter 3: estimating what another body feels, by sharing motions and asking questions."""
