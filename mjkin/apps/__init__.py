"""Applications built on the library: the command line, benchmarks, the playground, the demo scenes."""
