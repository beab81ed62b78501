"""The public surface of the package: what ``dir(symmon)`` lists, and the import paths kept."""

import importlib

import symmon as sm

#: Modules that implement the package but are not part of its interface.
IMPLEMENTATION = ("compile", "io", "latex", "progress", "ccache", "cnames")


def test_dir_lists_the_public_names_only():
    listed = dir(sm)
    assert not set(IMPLEMENTATION) & set(listed)
    assert set(sm.__all__) <= set(listed)
    assert all(hasattr(sm, name) for name in sm.__all__)


def test_implementation_modules_stay_importable():
    for name in IMPLEMENTATION:
        module = importlib.import_module(f"symmon.{name}")
        assert getattr(sm, name) is module


def test_split_modules_keep_the_old_import_paths():
    from symmon import expressions, invariance, modelfile, physical_units, units

    assert modelfile.parse_expression is expressions.parse_expression
    assert modelfile.ModelFileError is expressions.ModelFileError
    assert units.with_units is physical_units.with_units
    assert units.UnitModel is physical_units.UnitModel
    assert units.prove_invariance is invariance.prove_invariance
