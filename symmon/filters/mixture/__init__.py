"""The mixture family: the Gaussian-sum filter, interacting multiple models, mixture reduction
and their compiled kernel.  Names are imported from their modules, not from here."""
