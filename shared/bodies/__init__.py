"""MuJoCo bodies: the robot arms and human bodies built from a skeleton's segments, performing a
clip (inverse dynamics, torques), its support and balance, the feet kept planted. Imports
``motion``, ``io`` and ``errors``."""
