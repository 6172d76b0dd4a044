"""The Mitsuba 3 plugins (Dr.Jit only inside eval/sample/pdf): the shared parts, the BSDF, its
kernels, the sphere path, the ``corona_mie`` phase function and the media around it."""
