"""Pictures: the pygame renderer, the snapshot it draws, and matplotlib plots.

It owns: ``renderer`` (``human`` window and ``rgb_array`` frames, GIF/MP4 writing), ``state``
(``RenderState``, the plain snapshot the env hands over; rendering reads it and never feeds
observations) and ``plots`` (maps, trajectories and coverage curves for the commands). Only this
part imports pygame, and only when a renderer is made.
"""
