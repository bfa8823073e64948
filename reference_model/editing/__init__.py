"""Object editing through the scene graph (:mod:`.edits`): remove, keep only, move or copy objects."""
