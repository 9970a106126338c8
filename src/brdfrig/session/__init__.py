"""Capture sessions: configuration, plans, the crash-safe store, run/resume, the offline pipeline, figures."""
