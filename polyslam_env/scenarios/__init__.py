"""Shipped scenario files other than maps: precomputed robot paths (``paths``).

File formats only, importing nothing but ``core``, so that policies (the ``paper`` policy
replays the paper's paths) may read them without touching the world.
"""
