"""Replaying counterexamples through the real detector and tracker (docs/semantics.md, "Replay")."""
