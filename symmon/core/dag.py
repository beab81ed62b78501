"""Walks of sympy expressions as DAGs: each distinct node once, without recursion.

A traced loop (``for _ in range(100): x = x + 0.1 * np.sin(x)``, ``y = sin(y) + cos(y)``
iterated) builds an expression whose subexpressions are shared: a few hundred distinct
nodes, but a tree of 2¹⁰⁰ nodes, hundreds of levels deep.  sympy's own walks
(``free_symbols``, ``has``, ``str``, ``subs``, ``diff``) follow the tree recursively, so
they take exponential time or end in a ``RecursionError``.  The walks here keep an explicit
stack and visit each node once (nodes are told apart by identity, so no walk compares two
large expressions for equality): their cost is linear in the number of distinct nodes and
their depth is unbounded.

- :func:`postorder`: the distinct nodes, children before parents;
- :func:`free_symbols`, :func:`contains`: sympy's ``free_symbols`` and ``has(func)``;
- :func:`measure`: distinct nodes, the size of the tree and its depth (what a recursive
  sympy walk of it would cost), :func:`is_small` whether sympy may walk it;
- :func:`digest`: a structural hash, stable across processes, that keys the caches of
  compiled models;
- :func:`bounded_str`: ``str(e)``, or a summary when the printed tree would be too large;
- :func:`substitute`: ``xreplace`` that rebuilds each distinct node once.
"""

from __future__ import annotations

import hashlib
from typing import Callable, Iterable

import sympy as sp
from sympy.functions.elementary.piecewise import ExprCondPair

__all__ = ["postorder", "Canonical", "free_symbols", "contains", "measure", "is_small", "digest", "bounded_str",
           "substitute", "MAX_TREE", "MAX_DEPTH"]

#: Largest tree (counted with repetitions) that sympy's recursive walks are given.
MAX_TREE = 20000
#: Largest depth that sympy's recursive walks are given: a few Python frames a level, well
#: below Python's default recursion limit of 1000.
MAX_DEPTH = 120


def postorder(exprs: Iterable[sp.Basic], done: Callable[[sp.Basic], bool] | None = None) -> list[sp.Basic]:
    """The distinct nodes of ``exprs``, each once, every node after its arguments.

    Parameters
    ----------
    exprs : iterable of sympy.Basic
    done : callable, optional
        Nodes for which ``done(node)`` is true are left out with all their descendants
        (a walk that continues an earlier one passes what it has visited).

    Returns
    -------
    list of sympy.Basic
        Told apart by identity: two equal but separately built subexpressions are two
        entries (never more than the nodes that exist).

    Examples
    --------
    >>> x = sp.Symbol("x")
    >>> e = sp.sin(x) + sp.cos(x)
    >>> [str(n) for n in postorder([e * e])]
    ['x', 'cos(x)', 'sin(x)', 'sin(x) + cos(x)', '2', '(sin(x) + cos(x))**2']
    """
    seen: set[int] = set()
    order: list[sp.Basic] = []
    roots = [sp.sympify(e) for e in exprs]
    stack: list[tuple[sp.Basic, bool]] = [(e, False) for e in reversed(roots)]
    while stack:
        node, placed = stack.pop()
        if placed:
            order.append(node)
            continue
        if id(node) in seen:
            continue
        seen.add(id(node))
        if done is not None and done(node):
            continue
        stack.append((node, True))
        # In a DAG a child already seen is already in ``order``: only ancestors of the
        # node are seen but not yet placed, and a child is never an ancestor.
        stack.extend((a, False) for a in reversed(node.args) if id(a) not in seen)
    return order


# Classes whose free symbols are the union of their arguments' (sympy computes them the
# same way, but recursively); any other class with its own ``free_symbols`` (bound
# variables: Integral, Lambda, Subs, Derivative) is asked directly.
_UNION = (ExprCondPair,)


def _own_free_symbols(node: sp.Basic) -> bool:
    # Looked up in the MRO: a sympy function class's metaclass has its own free_symbols.
    owner = next(k for k in type(node).__mro__ if "free_symbols" in vars(k))
    return owner is not sp.Basic and not isinstance(node, _UNION)


def free_symbols(exprs: Iterable[sp.Basic] | sp.Basic) -> set[sp.Basic]:
    """The free symbols of ``exprs`` (one expression or several), as sympy's
    ``free_symbols``, in time linear in their distinct nodes."""
    roots = [exprs] if isinstance(exprs, sp.Basic) else list(exprs)
    sets: dict[int, frozenset] = {}
    for node in postorder(roots):
        if node.is_Symbol or not node.args or _own_free_symbols(node):
            sets[id(node)] = frozenset(node.free_symbols)
        else:
            sets[id(node)] = frozenset().union(*(sets[id(a)] for a in node.args))
    return set().union(*(sets[id(sp.sympify(e))] for e in roots))


def contains(expr: sp.Basic, func: type) -> bool:
    """Whether a node of ``expr`` is an instance of ``func`` (sympy's ``expr.has(func)``
    for a class)."""
    return any(isinstance(node, func) for node in postorder([expr]))


def substitute(exprs: Iterable[sp.Basic], mapping: dict) -> list[sp.Basic]:
    """``[e.xreplace(mapping) for e in exprs]``, each distinct node rebuilt once.

    sympy's ``xreplace`` rebuilds the tree: a node shared by many parents is rebuilt once per
    path to it, exponential on a traced loop or a composition of sub-steps
    (:func:`symmon.core.discretize.compose`).  Here the nodes are rebuilt in
    :func:`postorder` with sympy's evaluation off, so the result keeps the sharing (and
    folds nothing: a substituted number stays a leaf of its operation).

    Examples
    --------
    >>> x, b = sp.symbols("x b")
    >>> e = x + b
    >>> for _ in range(200):
    ...     e = e * e + b
    >>> out = substitute([e], {b: sp.Float(2.0)})[0]
    >>> measure([out])[0] == measure([e])[0], free_symbols([out]) == {x}   # the same DAG, b now 2.0
    (True, True)
    """
    done: dict[int, sp.Basic] = {}
    roots = [sp.sympify(e) for e in exprs]
    with sp.evaluate(False):
        for node in postorder(roots):
            if node in mapping:
                done[id(node)] = mapping[node]
            elif not node.args:
                done[id(node)] = node
            else:
                args = [done[id(a)] for a in node.args]
                done[id(node)] = node if all(a is b for a, b in zip(args, node.args)) else node.func(*args)
    return [done[id(e)] for e in roots]


def measure(exprs: Iterable[sp.Basic]) -> tuple[int, int, int]:
    """(distinct nodes, nodes of the tree, depth) of ``exprs``: what a walk that visits
    each node once costs, and what a recursive walk of the tree costs."""
    size: dict[int, int] = {}
    depth: dict[int, int] = {}
    nodes = postorder(exprs)
    for node in nodes:
        size[id(node)] = 1 + sum(size[id(a)] for a in node.args)
        depth[id(node)] = 1 + max((depth[id(a)] for a in node.args), default=0)
    roots = [id(sp.sympify(e)) for e in exprs]
    return len(nodes), sum(size[r] for r in roots), max((depth[r] for r in roots), default=0)


def is_small(exprs: Iterable[sp.Basic]) -> bool:
    """Whether sympy's recursive walks may be given ``exprs``: a tree of at most
    :data:`MAX_TREE` nodes and :data:`MAX_DEPTH` levels."""
    _, tree, depth = measure(exprs)
    return tree <= MAX_TREE and depth <= MAX_DEPTH


def _atom_text(node: sp.Basic) -> str:
    """What identifies an atom exactly: a symbol by name and assumptions, a number by its
    exact value (a Float by its binary mantissa, exponent and precision)."""
    if isinstance(node, sp.Dummy):
        return f"{node.name}|{node.dummy_index}|{sorted(node.assumptions0.items())}"
    if isinstance(node, sp.Symbol):
        return f"{node.name}|{sorted(node.assumptions0.items())}"
    if isinstance(node, sp.Float):
        return f"{node._mpf_}|{node._prec}"
    if isinstance(node, sp.Rational):
        return f"{node.p}/{node.q}"
    # Singletons (pi, E, oo, nan, true) are told apart by their class; any other atom
    # by sympy's exact text of it (an atom is small).
    return sp.srepr(node)


class Canonical:
    """Numbers for structurally equal nodes: ``classes[id(node)]`` is the same for two
    nodes of the same type with the same atom value, or with arguments of the same
    numbers in order.

    Equal expressions that sympy built as two objects (its cache of expressions is
    bounded) are so told equal without comparing their trees.

    Examples
    --------
    >>> x = sp.Symbol("x")
    >>> a = x + 1
    >>> b = sp.Add(*a.args, evaluate=False)
    >>> c = Canonical()
    >>> c.add(postorder([a, b]))
    >>> a is b, c.classes[id(a)] == c.classes[id(b)]
    (False, True)
    """

    def __init__(self) -> None:
        self.classes: dict[int, int] = {}
        self._index: dict[tuple, int] = {}

    def add(self, nodes: Iterable[sp.Basic]) -> None:
        """Number ``nodes``, given in post-order (:func:`postorder`); nodes already
        numbered are skipped."""
        for node in nodes:
            if id(node) in self.classes:
                continue
            args = node.args
            key = (type(node), tuple(self.classes[id(a)] for a in args) if args else _atom_text(node))
            self.classes[id(node)] = self._index.setdefault(key, len(self._index))


def digest(exprs: Iterable[sp.Basic]) -> str:
    """A structural hash of ``exprs`` in order: sha256 of each distinct node made of its
    class, its exact value if it is an atom and its arguments' hashes.

    Equal expressions have equal digests in every process (no salted ``hash()``); the
    cost is one short sha256 per distinct node, whatever the size of the tree.

    Examples
    --------
    >>> x, y = sp.symbols("x y")
    >>> digest([x + 1]) == digest([1 + x]) != digest([y + 1])
    True
    """
    roots = [sp.sympify(e) for e in exprs]
    hashes: dict[int, bytes] = {}
    for node in postorder(roots):
        cls = type(node)
        h = hashlib.sha256(f"{cls.__module__}.{cls.__qualname__}:{cls.__name__}".encode())
        if node.args:
            h.update(b"(")
            for a in node.args:
                h.update(hashes[id(a)])
        else:
            h.update(b"=" + _atom_text(node).encode())
        hashes[id(node)] = h.digest()
    top = hashlib.sha256(b"symmon-dag-1")
    top.update(len(roots).to_bytes(8, "little"))
    for r in roots:
        top.update(hashes[id(r)])
    return top.hexdigest()


def bounded_str(expr: sp.Basic, limit: int = 2000) -> str:
    """``str(expr)``, or, when its tree has more than ``limit`` nodes or is deeper than
    :data:`MAX_DEPTH` (printing it would take exponential time), a summary such as
    ``<Add of 301 distinct subexpressions, a tree of 2.5e+90 nodes>``."""
    distinct, tree, depth = measure([expr])
    if tree <= limit and depth <= MAX_DEPTH:
        return str(expr)
    return f"<{type(expr).__name__} of {distinct} distinct subexpressions, a tree of {float(tree):.3g} nodes>"
