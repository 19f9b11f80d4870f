"""The schema of a grasp run's files: report.json and each fold's checkpoint.json carry ``"schema"``
(a file without it is schema 0); resuming refuses a checkpoint of a newer schema in one line that
names it (:func:`ftorch.checkpoint.schema_of`). The learner state inside a checkpoint has its own
schema (:mod:`ftorch.grasp.state`).

Schema versions:

- 0: files written before the schema was numbered; they read as they are (no migration).
- 1: the same contents, numbered.
"""

SCHEMA = 1
