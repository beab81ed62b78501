"""Files: the whitelisted expression language (:mod:`.expressions`, never ``eval``), the
model-file schema (:mod:`.modelfile`, docs/reference/modelfile.md), the particle files
(:mod:`.samplefile`) and the filter scenario
files (:mod:`.filterfile`)."""

from .filterfile import FilterSpec as FilterSpec
from .filterfile import load_filter_file as load_filter_file
from .modelfile import ModelSpec as ModelSpec
from .modelfile import dump_model_file as dump_model_file
from .modelfile import load_model_file as load_model_file
from .samplefile import load_samples_file as load_samples_file

__all__ = ["ModelSpec", "load_model_file", "dump_model_file", "FilterSpec", "load_filter_file", "load_samples_file"]
