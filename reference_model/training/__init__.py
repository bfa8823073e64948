"""Training a WeatherCity model: views of a scene (:mod:`.views`), the model built from its lidar
(:mod:`.build`), the losses (:mod:`.losses`), densification (:mod:`.densify`), the optimisation loop
(:mod:`.trainer`), checkpoints (:mod:`.checkpoint`) and the named settings (:mod:`.config`)."""
