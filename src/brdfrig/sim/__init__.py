"""Simulated devices: GRBL firmware on a pseudo-terminal, a camera writing DNGs, the whole bench (tests and demo only)."""
