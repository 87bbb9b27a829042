"""The verify workflow: video in, verdicts, replays and a report out (paper section 8)."""
