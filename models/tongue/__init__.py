"""The ArtiSynth hex tongue: data readers, fibers, refinement and the model."""
