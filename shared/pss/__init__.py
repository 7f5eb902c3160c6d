"""The Proto-symbol Space (thesis ch. 2): left-to-right HMMs (``hmm``, ``likelihood``), their eq.
2.4 distances (``distance``), metric MDS (``mds``), the space (``space``: build, recognise, generate,
emphasise), association (``association``), the space's file (``spacefile``), recognition's open
set (``recognition``, ``novelty``, ``conformal``), motion features (``features``). Imports
``motion``, ``io``, ``bodies`` (torques as sensor channels) and the base modules; never the bus."""
