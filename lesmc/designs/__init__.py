"""The registry of designs (lesmc/designs/registry.py): trackers, and the monitor on top."""
