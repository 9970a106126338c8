"""Exports of a BRDF for other tools (MERL tables, grids, Mitsuba, OpenPBR/MaterialX, glTF), each with its error."""
