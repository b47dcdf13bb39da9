"""What every layer stands on: kernel compiles (jit, tier, cache, numba_private), shared intrinsics, files, checks.

The intrinsics the kernels share are in numba_ext; threads in parallel, progress on stderr in progress.
"""
