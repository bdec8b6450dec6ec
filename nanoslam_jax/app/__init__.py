"""The application on top of the library: the configuration (schema, YAML, validation and its
reference), the method registry, the engine that loads, builds, runs, scores and writes a run
(:mod:`.experiment`), comparisons, sweeps, studies, the compilation cache and the command line."""

__all__: list[str] = []
