"""The simulation campaign (`normbox-lab sim campaign`): random scenarios of faults and operator
actions (`scenario`), run against the simulated lab through the product's own command line in
forked segments (`harness`), judged by an oracle that knows the virtual world's truth
(`invariants`), and shrunk to a minimal replay when something breaks (`campaign`).

It stands above the analysis (its oracle reads what the lab stored and what the analysis made
of it) and below the command line that starts it; `sim/` below holds the emulators and the
worlds only."""
