"""Where runs live and how they run: run folders and their files, the atomic writer and
the folder lock, JAX's compilation cache, devices and sharding, multi-process launch.
"""
