"""What a real scene's frames and lidar say about it, beyond the lidar's reach (docs/design.md §7).

Per scene, once: which lidar returns are static (:mod:`.motion`), which pixels show the sky
(:mod:`.sky`), where the ego vehicle's own body sits in the image (:mod:`.ego`) and where the sun
came from and what it lit (:mod:`.sun`). :func:`~.analysis.analyse_scene` runs them together for
the weather editor and WeatherCity's training views. numpy, OpenCV and SciPy only (no torch).
"""
