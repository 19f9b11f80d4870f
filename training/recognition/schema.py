"""The schema of a recognition run's files: report.json and each fold's checkpoint.json carry
``"schema"`` (a file without it is schema 0), and :func:`migrated_config` applies one migration per
version to the run config they record, for resume, robustness and the trade-off alike. The learner
state inside a checkpoint, and learner.json, have their own schema (:mod:`ftorch.recognition.state`),
whose rule for the learner's options the configs share.

Schema versions:

- 0: files written before the schema was numbered. An option a run's config does not record ran at
  its value before the option existed: the learner's by :func:`ftorch.recognition.state.options_before`,
  dynamic views off (``dynamic``).
- 1: every option recorded.
- 2: ``distinctions`` recorded; a version 1 run learned one class pair per expert search (``pair``:
  :func:`ftorch.recognition.state.distinctions_before`, the learner states' rule).
"""
from __future__ import annotations

from ftorch.checkpoint import schema_of
from ftorch.recognition.state import distinctions_before, options_before

SCHEMA = 2


def _config_schema_0(config: dict) -> dict:
    """Version 0 to 1 (module doc)."""
    return {**options_before(config), "dynamic": False, **config}


MIGRATIONS = {0: _config_schema_0, 1: distinctions_before}  # version -> the config one version on


def migrated_config(config: dict, version, what: str) -> dict:
    """``config``, as a file of schema ``version`` (None: 0) recorded it, brought to :data:`SCHEMA`;
    InputError naming ``what`` for a newer file, ValueError for no version number."""
    version = schema_of(version, what, SCHEMA)
    for step in range(version, SCHEMA):
        config = MIGRATIONS[step](config)
    return config
