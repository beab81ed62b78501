"""``symmon verify FILE.toml`` (issue 37, item 4): exit 0 when every claim passes, 1 when one is
refuted (or misses its expected verdict) or the file is bad, 2 on a usage error."""

from __future__ import annotations

import json
import textwrap

import pytest

from symmon.cli import parser as cli

GOOD = """
title = "two claims"
[symbols]
mu = "real"
sigma = "positive"
[gaussian]
variables = ["x"]
mean = ["mu"]
cov = [["sigma**2"]]
[[claims]]
name = "second moment"
lhs = "expect(x**2)"
rhs = "mu**2 + sigma**2"
[[claims]]
name = "a printed error, on record"
lhs = "expect(x**2)"
rhs = "mu**2"
expect = "refuted"
"""


def run(capsys, *argv):
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def good(tmp_path):
    path = tmp_path / "good.toml"
    path.write_text(textwrap.dedent(GOOD), encoding="utf-8")
    return path


def test_every_claim_passing_exits_0(capsys, good):
    code, out, _ = run(capsys, "verify", str(good), "--points", "3")
    assert code == 0
    assert "PASS  second moment: proved" in out and "PASS  a printed error, on record: refuted, expected refuted" in out
    assert "2 claims: 1 proved, 0 consistent, 1 refuted; all pass" in out
    assert "counterexample: at mu =" in out


def test_a_refuted_claim_exits_1(capsys, good, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(good.read_text().replace('expect = "refuted"\n', ""), encoding="utf-8")
    code, out, _ = run(capsys, "verify", str(bad), "--points", "3")
    assert code == 1 and "FAIL  a printed error, on record: refuted" in out and "FAILED" in out


def test_a_claim_missing_its_expected_proof_exits_1(capsys, good, tmp_path):
    """expect = "proved" is not met by a consistent verdict (E[atan x] = 0: no closed form)."""
    path = tmp_path / "p.toml"
    path.write_text(good.read_text() + '[[claims]]\nlhs = "expect(atan(x - mu))"\nrhs = "0"\nexpect = "proved"\n',
                    encoding="utf-8")
    code, out, _ = run(capsys, "verify", str(path), "--points", "2")
    assert code == 1 and "consistent, expected proved" in out


def test_json_output(capsys, good):
    code, out, _ = run(capsys, "verify", str(good), "--json", "--points", "2", "--seed", "3")
    data = json.loads(out)
    assert code == 0 and data["passed"] is True and data["title"] == "two claims"
    assert [c["verdict"] for c in data["claims"]] == ["proved", "refuted"]
    assert data["claims"][1]["counterexample"]["point"].keys() == {"mu", "sigma"}


def test_a_bad_file_exits_1_and_a_bad_option_2(capsys, tmp_path, good):
    evil = tmp_path / "evil.toml"
    evil.write_text('[[claims]]\nlhs = "__import__(\'os\').getcwd()"\nrhs = "1"\n', encoding="utf-8")
    code, _, err = run(capsys, "verify", str(evil))
    assert code == 1 and "attribute access is not allowed" in err
    code, _, err = run(capsys, "verify", str(tmp_path / "missing.toml"))
    assert code == 1 and "not found" in err
    code, _, err = run(capsys, "verify", str(good), "--points", "0")
    assert code == 2


SIGN = """
title = "a jump in two dimensions (issue 47)"
[gaussian]
variables = ["x1", "x2"]
mean = ["1/3", "18/5"]
cov = [["100/9", 0], [0, "1/9"]]
[[claims]]
name = "E sign(x1 x2) = E sign(x1) E sign(x2)"
lhs = "expect(sign(x1*x2))"
rhs = "(2*Phi(1/10) - 1)*(2*Phi(54/5) - 1)"
[[claims]]
name = "E sign(x1 x2) = 0, false"
lhs = "expect(sign(x1*x2))"
rhs = "0"
expect = "refuted"
"""


def test_a_jump_is_checked_against_an_honest_reference(capsys, tmp_path):
    path = tmp_path / "sign.toml"
    path.write_text(textwrap.dedent(SIGN), encoding="utf-8")
    code, out, _ = run(capsys, "verify", str(path), "--points", "2")
    assert code == 0, out
    assert "PASS  E sign(x1 x2) = E sign(x1) E sign(x2): consistent" in out
    assert "PASS  E sign(x1 x2) = 0, false: refuted, expected refuted" in out
    assert "Gauss-Hermite" not in out
