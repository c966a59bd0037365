"""Bounded fuzzing of rmbuild's inputs: every input format, the config and the anchors.

A case is (kind, seed): a valid base input of that kind, a few seeded mutations (hostile cells and times,
overlong lines, garbage bytes, truncation, non-UTF-8, deep nesting, ...), and the command that reads it.
The cases run in a worker process under a memory cap; each must end with exit 0 or 2, an error of one
line naming a file of the case, no traceback, nothing written on failure, bounded memory and time.

``python -m bench.fuzz --cases 10000`` (``make fuzz``) writes bench/results/fuzz.json; the test suite runs
a few hundred cases through :func:`bench.fuzz.run.run_cases` (tests/test_fuzz.py).
"""
