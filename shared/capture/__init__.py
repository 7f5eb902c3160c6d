"""Live capture: a BVH stream over TCP recorded into takes (``stream``), repetitions of a target
found in a take (``segment``), takes joined from clips with their true boundaries (``takes``),
the adverb said aloud (``speech``). Imports ``motion``, ``io``, ``pss`` and the base modules."""
