"""Acquisition: lab config and assembly, the run engine, operator, store, exports and importers."""
