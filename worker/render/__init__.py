"""GL rendering: the EGL context, scene buffers, textures, foliage, staging, the cull pass,
cameras, clips."""
