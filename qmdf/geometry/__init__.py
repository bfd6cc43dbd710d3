"""Plain geometry functions over numpy arrays: input io, normalisation, procedural shapes, topology."""
