"""The check pipeline: a job (what to verify) in, typed results out (docs/architecture.md)."""

from lesmc.pipeline.check import run
from lesmc.pipeline.job import Job, Unit

__all__ = ["Job", "Unit", "run"]
