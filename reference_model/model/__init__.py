"""The WeatherCity scene model (torch): weather Gaussians on the scene graph.

Every Gaussian of the background, rigid and non-rigid nodes carries a shared feature
(:mod:`.gaussians`); one small decoder per weather turns features into colors (:mod:`.decoders`);
a per-weather environment map draws the sky (:mod:`.sky`); :mod:`.scene_model` assembles the nodes
of a frame and renders every weather's colors in one rasterization pass (docs/design.md §7).
"""
