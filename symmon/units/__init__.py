"""Units: changes of units of a model and of Gaussians (the affine map (18), (20), (35)),
physical units with pint, and the symbolic proofs of unit invariance of the measures
(Straka & Havlík 2024, Sections III–IV; docs/guide/units.md).

Direction convention: **S maps new-unit numbers to old-unit numbers**: column k of S is
the old-unit value of one new unit of component k (m → km gives S = 1000).

- :func:`change_units`, :func:`changed_relation`, :func:`change_gaussian`: the model and
  the distributions in new units, with exact sympy matrices;
- :func:`with_units`, :class:`UnitModel`: physical units declared with pint (:mod:`.physical`);
- :func:`prove_invariance`, :func:`prove_matrix_invariance`, :class:`InvarianceProof`: the
  proofs (:mod:`.proofs`, :mod:`.matrix`, :mod:`.proof`) and their lemmas (:mod:`.lemmas`).
"""

from ..core.rescale import change_gaussian as change_gaussian
from ..core.rescale import change_units as change_units
from ..core.rescale import changed_relation as changed_relation
from ..errors import UnitError as UnitError
from .matrix import prove_matrix_invariance as prove_matrix_invariance
from .physical import UnitModel as UnitModel
from .physical import with_units as with_units
from .proof import InvarianceProof as InvarianceProof
from .proofs import prove_invariance as prove_invariance

__all__ = ["UnitError", "change_units", "change_gaussian", "changed_relation", "with_units", "UnitModel",
           "InvarianceProof", "prove_invariance", "prove_matrix_invariance"]
