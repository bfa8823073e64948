"""The Gaussian scene graph: Gaussian sets (:mod:`.gaussians`), nodes placed per frame
(:mod:`.nodes`) and the initialisation of a scene from its lidar (:mod:`.lidar_init`)."""
