"""The particle family: the particle filter, its compiled kernel and random streams.
Names are imported from their modules, not from here."""
