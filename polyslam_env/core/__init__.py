"""Shared basics every other part may use, and which import nothing else of the package.

It owns: the frozen-dataclass config base with strict YAML loading (``config``), the error
types (``errors``), SE(2) and angle helpers (``geometry``), named seed streams (``seeding``),
atomic file writes (``io``), where the shipped ``configs/`` live (``resources``) and the BLAS
thread cap used around a SLAM step (``blas``).
"""
