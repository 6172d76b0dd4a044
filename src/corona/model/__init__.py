"""The model: form factors, structure factors, Mie theory and the layer's material (numpy/scipy only)."""
