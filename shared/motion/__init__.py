"""The motion data model: :class:`clip.Clip` (frames x named channels, its skeleton, label),
:class:`skeleton.Skeleton` (joints, Euler conventions, units), forward kinematics, and where an AMC
file's skeleton lies. Imports only ``shared.errors`` and ``shared.compiled``."""
