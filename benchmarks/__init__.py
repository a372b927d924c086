"""The benchmarks: scripts run as `python benchmarks/<name>.py`, each importing its
siblings by name (`_bench`, `_results`, `study`, `scenes`, ...).

This file makes the folder a package so that tests can import the modules they share
with it, which import no sibling: `benchmarks.scenes` (scenes and hard cases),
`benchmarks.reference_model` (the independent SciPy model) and `benchmarks.fuzz_cases`
(hostile inputs). pytest puts the repository root on the path (`pythonpath` in
pyproject.toml).
"""
