"""Physically based weather appearance on a scene's own surfaces: the built-in weather editor.

:mod:`.shading` holds the models (overcast light, wet albedo, Fresnel, snow cover, haze),
:mod:`.surfaces` the lidar Gaussians with their surface attributes, :mod:`.maps` their per-view
rendering and completion, and :mod:`.editor` the editor that puts them together.
"""
