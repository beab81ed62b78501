"""The public surface of the package: what ``dir(symmon)`` lists, and where each name lives."""

import importlib

import symmon as sm

#: Subpackages and modules that implement the package but are not part of its interface.
IMPLEMENTATION = ("core", "compile", "propagation", "measures", "files", "cli", "reproduce", "io", "latex",
                  "progress", "derive")


def test_dir_lists_the_public_names_only():
    listed = dir(sm)
    assert not set(IMPLEMENTATION) & set(listed)
    assert set(sm.__all__) <= set(listed)
    assert all(hasattr(sm, name) for name in sm.__all__)


def test_implementation_modules_stay_importable():
    for name in IMPLEMENTATION:
        module = importlib.import_module(f"symmon.{name}")
        assert module.__name__ == f"symmon.{name}"


def test_public_modules_are_their_homes():
    """The module names of ``sm.__all__`` are the subpackage modules that define the names."""
    homes = {"angles": "symmon.core.angles", "problems": "symmon.core.problems", "kalman": "symmon.filters.gaussian.linear",
             "modelfile": "symmon.files.modelfile", "mmse": "symmon.estimation.mmse",
             "sweep": "symmon.measures.sweep", "weights": "symmon.measures.weights", "units": "symmon.units",
             "estimation": "symmon.estimation", "filters": "symmon.filters", "codegen": "symmon.codegen",
             "transforms": "symmon.transforms", "errors": "symmon.errors"}
    for name, home in homes.items():
        assert getattr(sm, name) is importlib.import_module(home), name


def test_each_public_name_has_one_home():
    from symmon.files import expressions, modelfile
    from symmon.measures import formula, mon
    from symmon.units import lemmas, physical, proofs

    assert modelfile.parse_expression is expressions.parse_expression
    assert modelfile.ModelFileError is sm.errors.ModelFileError
    assert sm.units.with_units is physical.with_units and sm.units.UnitModel is physical.UnitModel
    assert sm.units.prove_invariance is proofs.prove_invariance
    assert proofs.lemma_weight is lemmas.lemma_weight and proofs.Lemma is lemmas.Lemma
    assert mon.mon_from_moments is formula.mon_from_moments is sm.mon_from_moments
    assert mon.NonlinearityMeasure is formula.NonlinearityMeasure is sm.NonlinearityMeasure
    assert sm.KalmanFilter is sm.filters.KalmanFilter is sm.kalman.KalmanFilter
    assert sm.units.change_units is sm.core.change_units
