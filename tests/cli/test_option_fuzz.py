"""Fuzzing the ``symmon`` command's option values (issue 13): each parses within its declared
limit (:mod:`symmon.cli.options`) or is a usage error, exit 2, never an exception.

The parser is the private ``symmon.cli.parser._parser``; the model file is never read. The
runs are derandomized and use no example database, as in tests/test_fuzz.py.
"""

from __future__ import annotations

import contextlib
import io

from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from symmon.cli import parser as cli

#: Reproducible and bounded: the same examples on every run, no deadline per example.
FUZZ = dict(derandomize=True, database=None, deadline=None,
            suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

text_no_surrogates = st.text(st.characters(blacklist_categories=("Cs",)), max_size=12)

option_text = st.one_of(
    st.integers(-(10**20), 10**20).map(str),
    st.sampled_from(("", "0", "-0", "1e3", "0x10", "nan", "inf", "1:2:3", "0.1:10:1001", "1:1:1000", "a:b:c",
                     "threads", "tcp://h:1", "tcp://h:65536", "h:", ":1", "tls://[::1]:8786", "inproc://h/1/1",
                     "out.png", "out.PDF", "out", "out.xyz", ".png", "x" * 300, "-", "--", "9" * 5000)),
    text_no_surrogates,
)
OPTIONS = ("--samples", "--seed", "--order", "--groups", "--workers", "--dask", "--dask-timeout", "--alpha-sweep",
           "--plot", "--csv")


@settings(max_examples=300, **FUZZ)
@given(option=st.sampled_from(OPTIONS), value=option_text)
def test_option_values_parse_within_their_limits_or_exit_2(option, value):
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            args = cli._parser().parse_args(["nonlinearity", "m.toml", option, value])
    except SystemExit as exc:
        event("usage error")
        assert exc.code == 2 and "usage: symmon nonlinearity" in err.getvalue()
        return
    event("accepted")
    limits = {"samples": (1, cli.MAX_SAMPLES), "seed": (0, cli.MAX_SEED), "order": (1, cli.MAX_ORDER),
              "groups": (1, cli.MAX_GROUPS), "workers": (1, cli.MAX_WORKERS)}
    dest = option.lstrip("-").replace("-", "_")
    if dest in limits:
        lo, hi = limits[dest]
        assert lo <= getattr(args, dest) <= hi
    elif dest == "dask_timeout":
        assert 0 < args.dask_timeout <= cli.MAX_WORKER_TIMEOUT
    elif dest == "alpha_sweep":
        assert 1 <= len(args.alpha_sweep) <= cli.MAX_SWEEP_POINTS
    else:
        assert getattr(args, dest)  # a path or a target is never empty
