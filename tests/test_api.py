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
    from symmon import expressions, invariance, lemmas, modelfile, physical_units, units

    assert modelfile.parse_expression is expressions.parse_expression
    assert modelfile.ModelFileError is expressions.ModelFileError
    assert units.with_units is physical_units.with_units
    assert units.UnitModel is physical_units.UnitModel
    assert units.prove_invariance is invariance.prove_invariance
    assert invariance.lemma_weight is lemmas.lemma_weight and invariance.Lemma is lemmas.Lemma
    measure = importlib.import_module("symmon.measure")
    nonlinearity = importlib.import_module("symmon.nonlinearity")  # sm.nonlinearity is the function
    assert nonlinearity.mon_from_moments is measure.mon_from_moments is sm.mon_from_moments
    assert nonlinearity.NonlinearityMeasure is measure.NonlinearityMeasure is sm.NonlinearityMeasure


def _results():
    import numpy as np
    import sympy as sp

    from symmon import estimation, invariance, units

    x, y = sp.symbols("x y", real=True)
    kf = sm.KalmanFilter(np.eye(2), 0.1 * np.eye(2), np.eye(2), np.eye(2))
    polar = sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)], name="polar")
    line = sm.Model([x], [2 * x])
    return {
        "Gaussian": (sm.Gaussian([1.0, 2.0], np.eye(2)), "N([1, 2], [[1, 0], [0, 1]])"),
        "KalmanFilter": (kf, "KalmanFilter(n=2, n_y=2)"),
        "KalmanResult": (kf.filter(np.zeros((3, 2)), np.zeros(2), np.eye(2)),
                         "KalmanResult(steps=3, n=2, n_y=2, last x̂ [0, 0], last std [0.571, 0.571])"),
        "KalmanResult bank": (kf.filter(np.zeros((4, 3, 2)), np.zeros(2), np.eye(2)),
                              "KalmanResult(runs=4, steps=3, n=2, n_y=2)"),
        "GeneralWeight": (sm.weights.general([0.5, 0.5], [[0.0, 0.1], [0.1, 0.0]]),
                          "GeneralWeight(alphas=(0.5, 0.5), offdiag=[[0.0, 0.1], [0.1, 0.0]])"),
        "Lemma": (invariance.lemma_cholesky(), "Lemma('cholesky-equivariance', holds=True)"),
        "UnitModel": (units.with_units(polar, {"x": "m", "y": "m"}, ["m", "rad"]),
                      "UnitModel('polar', inputs={'x': 'meter', 'y': 'meter'}, outputs={'y0': 'meter', 'y1': 'radian'})"),
        "DirectResult": (estimation.direct(line, [sm.Gaussian([2.0], [[1.0]])], sm.UT.ut1()),
                         "DirectResult(estimates=1, fused=N([4], [[4]]))"),
        "IndirectResult": (estimation.indirect(line, sm.Gaussian([0.0], [[1.0]]), [[2.0]], noise=[[1.0]],
                                               transform=sm.UT.ut1()),
                           "IndirectResult(measurements=1, posterior=N([0.8], [[0.2]]))"),
    }


def test_results_print_readably():
    for name, (obj, expected) in _results().items():
        assert repr(obj) == expected, name
