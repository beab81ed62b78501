"""The compiler: sympy → CasADi, exact derivatives, batched evaluators, C code and its cache
(docs/compile.md).  :func:`compiled` is the one way from a :class:`~symmon.Model` to its
:class:`CompiledModel`."""

from .ccache import NativeLibrary as NativeLibrary
from .ccache import build_shared_library as build_shared_library
from .ccache import cache_dir as cache_dir
from .ccache import compile_mode as compile_mode
from .ccache import has_compiler as has_compiler
from .cnames import c_identifier as c_identifier
from .cnames import comment_text as comment_text
from .compiled import CompiledModel as CompiledModel
from .compiled import batched as batched
from .compiled import compile_model as compile_model
from .compiled import compiled as compiled
from .compiled import compiled_with_params as compiled_with_params
from .compiled import model_key as model_key
from .compiled import to_casadi as to_casadi

__all__ = ["CompiledModel", "batched", "compiled", "compiled_with_params", "compile_model", "model_key", "to_casadi", "NativeLibrary", "build_shared_library",
           "cache_dir", "compile_mode", "has_compiler", "c_identifier", "comment_text"]
