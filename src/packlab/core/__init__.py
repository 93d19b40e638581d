"""The contract layer every other package builds on.

- :mod:`.types`: frozen dataclasses (Box, Container, Case, Action, Observation, ...).
- :mod:`.errors`: the exception types and exit codes.
- :mod:`.protocols`: ``Policy`` and ``TransitionBackend``.
- :mod:`.feasibility`: paper Eq. 2, footprint bounds, the shared candidate search, action masks.
- :mod:`.choices`: every named choice as a ``Literal`` type.
- :mod:`.fileio`: atomic writes.
- :mod:`.records`: typed, versioned records on disk (bench episodes and summary, dataset info),
  with their format versions, migrations and errors naming file, line, field and value.

Nothing here imports another packlab package (import-linter checks it).
"""
