"""What every layer stands on: kernel compiles (jit, tier, cache), threads, progress, atomic files, option checks."""
