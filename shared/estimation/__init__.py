"""Chapter 3: estimating what another body feels, by sharing motions and asking questions: the
words (``symbols``, ``language``), the conversation sets (``conversation``), the body estimator
(``body``) and its correction (``correction``), rule identification (``rules``). Imports
``pss``, ``bodies``, ``motion``, ``io``; never the bus (the services carry the questions)."""
