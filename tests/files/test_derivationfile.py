"""Derivation files (issue 37, item 4): read by the whitelist parser, never executed; each claim kind."""

from __future__ import annotations

import textwrap

import pytest

from symmon.errors import ModelFileError
from symmon.files.derivationfile import MAX_CLAIMS, check_derivation_file, load_derivation_file

HEAD = """
title = "test"
[symbols]
mu = "real"
sigma = "positive"
a = "real"
b = "real"
c = "real"
[gaussian]
variables = ["x"]
mean = ["mu"]
cov = [["sigma**2"]]
[models.sq]
inputs = ["u"]
outputs = ["u**2"]
mean = ["mu"]
cov = [["sigma**2"]]
"""


def write(tmp_path, body: str, head: str = HEAD):
    path = tmp_path / "claims.toml"
    path.write_text(textwrap.dedent(head) + textwrap.dedent(body), encoding="utf-8")
    return path


def verdicts(tmp_path, body: str) -> list[str]:
    _, vs = check_derivation_file(write(tmp_path, body), points=4)
    return [v.verdict for v in vs]


def test_each_claim_kind_is_checked(tmp_path):
    body = """
    [[claims]]
    lhs = "expect(x**2)"
    rhs = "mu**2 + sigma**2"
    [[claims]]
    kind = "moments"
    model = "sq"
    transform = "tt1"
    mean = ["mu**2"]
    cov = [["4*mu**2*sigma**2"]]
    cross_cov = [["2*mu*sigma**2"]]
    [[claims]]
    kind = "jacobian"
    model = "sq"
    value = [["2*u"]]
    [[claims]]
    kind = "hessian"
    model = "sq"
    value = [[["2"]]]
    [[claims]]
    kind = "mon"
    model = "sq"
    transform = "tt1"
    weight = "liu-li-raw"
    value = "0"
    [[claims]]
    kind = "weight"
    weight = "diag"
    cov = [["a", "b"], ["b", "c"]]
    value = [["1/(2*a)", "0"], ["0", "1/(2*c)"]]
    [[claims]]
    kind = "estimator"
    target = "x**2"
    estimator = "mu**2"
    bias = "sigma**2"
    mse = "4*mu**2*sigma**2 + 2*sigma**4 + sigma**4"
    """
    assert verdicts(tmp_path, body) == ["proved"] * 7


def test_expected_verdicts_and_phi_functions(tmp_path):
    body = """
    [[claims]]
    name = "an erratum on record"
    lhs = "expect(x**2)"
    rhs = "mu**2 + sigma"
    expect = "refuted"
    [[claims]]
    lhs = "Phi(mu) + Phi(-mu)"
    rhs = "1"
    expect = "proved"
    [[claims]]
    lhs = "phi(mu) * sqrt(2*pi)"
    rhs = "exp(-mu**2/2)"
    [[claims]]
    lhs = "max(mu, a)"
    rhs = "mu"
    assumptions = ["mu >= a"]
    """
    spec, vs = check_derivation_file(write(tmp_path, body), points=4)
    assert [v.verdict for v in vs][:3] == ["refuted", "proved", "proved"]
    assert vs[3].passed
    assert [c.passes(v) for c, v in zip(spec.claims, vs)] == [True] * 4
    assert spec.claims[0].name == "an erratum on record"


@pytest.mark.parametrize("expr, reason", [
    ("__import__('os').system('touch PWNED')", "attribute"),
    ("x.__class__", "attribute"),
    ("(lambda: 1)()", "lambda"),
    ("open('claims.toml')", "unknown function"),
    ("eval('1')", "unknown function"),
    ("[mu, mu]", "lists"),
    ("mu if mu else sigma", "conditional"),
    ("'text'", "string"),
    ("9**9**9", "power towers"),
    ("expect", "must be called"),
    ("expect(x, x)", "wrong number"),
    ("nu + 1", "unknown name"),
])
def test_unsafe_or_unknown_input_is_refused_never_run(tmp_path, monkeypatch, expr, reason):
    monkeypatch.chdir(tmp_path)
    body = f'[[claims]]\nlhs = "{expr}"\nrhs = "1"\n'
    with pytest.raises(ModelFileError, match=reason):
        load_derivation_file(write(tmp_path, body.replace('"', "'") if '"' in expr else body))
    assert not (tmp_path / "PWNED").exists()


@pytest.mark.parametrize("body, match", [
    ('[[claims]]\nkind = "proof"\nlhs = "1"\nrhs = "1"\n', "kind"),
    ('[[claims]]\nlhs = "1"\n', "missing key"),
    ('[[claims]]\nlhs = "1"\nrhs = "1"\nexpect = "true"\n', "expect"),
    ('[[claims]]\nlhs = "1"\nrhs = "1"\nsecret = 1\n', "unknown key"),
    ('[[claims]]\nkind = "jacobian"\nmodel = "nope"\nvalue = [["1"]]\n', "models.NAME"),
    ('[[claims]]\nkind = "jacobian"\nmodel = "sq"\nvalue = [["1", "2"]]\n', "matrix"),
    ('[[claims]]\nkind = "weight"\nweight = "heavy"\ncov = [["a"]]\nvalue = [["1"]]\n', "weight"),
    ('[[claims]]\nlhs = "mu"\nrhs = "mu"\nassumptions = ["mu = 1"]\n', "must be 'a < b'"),
    ('[domain]\nnu = [0, 1]\n[[claims]]\nlhs = "1"\nrhs = "1"\n', "not a symbol"),
    ('[domain]\nmu = [1, 0]\n[[claims]]\nlhs = "1"\nrhs = "1"\n', "low < high"),
    ('[[claims]]\nlhs = "expect(x) + expect(atan(x))"\nrhs = "1"\n', "no closed form"),
])
def test_bad_files_are_refused_with_the_key(tmp_path, body, match):
    with pytest.raises(ModelFileError, match=match):
        load_derivation_file(write(tmp_path, body))


def test_bad_symbols_and_gaussian_are_refused(tmp_path):
    with pytest.raises(ModelFileError, match="must be one of"):
        load_derivation_file(write(tmp_path, '[[claims]]\nlhs = "1"\nrhs = "1"\n', head='[symbols]\nmu = "huge"\n'))
    with pytest.raises(ModelFileError, match="reserved"):
        load_derivation_file(write(tmp_path, '[[claims]]\nlhs = "1"\nrhs = "1"\n', head='[symbols]\nPhi = "real"\n'))
    with pytest.raises(ModelFileError, match="gaussian"):
        load_derivation_file(write(tmp_path, '[[claims]]\nlhs = "expect(mu)"\nrhs = "mu"\n',
                                   head='[symbols]\nmu = "real"\n'))


def test_an_empty_list_of_claims_is_refused(tmp_path):
    with pytest.raises(ModelFileError, match="non-empty"):
        load_derivation_file(write(tmp_path, "claims = []\n", head='title = "t"\n'))


def test_too_many_claims_are_refused(tmp_path):
    body = '[[claims]]\nlhs = "1"\nrhs = "1"\n' * (MAX_CLAIMS + 1)
    with pytest.raises(ModelFileError, match=f"at most {MAX_CLAIMS}"):
        load_derivation_file(write(tmp_path, body))
