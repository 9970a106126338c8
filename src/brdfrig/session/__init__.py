"""Capture sessions: plan, run on the rig, store, resume, refit; the ``brdfrig`` CLI."""
