"""Types, errors, the injected clock, device capabilities and the neutral transport."""
