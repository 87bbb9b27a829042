"""The check pipeline: a job (what to verify) in, typed results out (docs/architecture.md)."""
