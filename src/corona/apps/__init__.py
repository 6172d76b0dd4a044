"""Applications on top of the model and the plugin: the CLI, renders, sweeps, fits, the designer,
pictures, the corona pass, scenes and micrographs."""
