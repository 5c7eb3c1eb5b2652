"""C routines of libraries the process has already loaded, called from compiled (numba) code.

Two hot calls of the scout loop go through Python bindings whose wrappers cost more than the routine itself:
quadprog's `solve_qp` (argument checks, four array copies, five allocations around `qpgen2_`, ≈ 2 µs of work)
and MuJoCo's `mj_step` (one binding call per physics step). `c_function(library, name)` looks the routine's
address up once (ctypes, in the library the binding itself loaded, so the same code and the same global state);
`ccall_void(address, args)` / `ccall_int(address, args)` call it from a compiled function with `args` a tuple
of arrays (passed as pointers to their first element), 32-bit integers (C `int`s) and 64-bit integers (passed as
pointers: the addresses of MuJoCo's `mjModel`/`mjData`). The routine runs on the same inputs as through its binding, so its results are the same bit for bit
(tests/scout_agent/test_ccall.py checks both against their bindings).

The address is an argument, not a constant of the compiled code: numba's on-disk cache stays valid across
processes (the library may load at another address).
"""

from __future__ import annotations

import ctypes
from collections.abc import Callable
from pathlib import Path
from typing import Any, cast

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic


def package_library(package_dir: str | Path, stem: str) -> Path:
    """The shared library `stem` shipped in a package's directory (`libmujoco.so.4.0.0`, `.dylib`, `.dll`)."""
    found = sorted(p for p in Path(package_dir).glob(f"{stem}*") if p.suffix != ".py")
    if not found:
        raise RuntimeError(f"no shared library {stem}* in {package_dir}")
    return found[0]


def c_function(library: str | Path, name: str) -> int:
    """The address of the exported C function `name` in the shared library at `library` (one already loaded:
    dlopen then returns the loaded copy)."""
    lib = ctypes.CDLL(str(library))
    try:
        fn = getattr(lib, name)
    except AttributeError as e:
        raise RuntimeError(f"{library} exports no C function {name!r}") from e
    address = ctypes.cast(fn, ctypes.c_void_p).value
    if not address:
        raise RuntimeError(f"{library}: {name!r} has no address")
    return int(address)


def _pointer_or_value(context, builder, t, v):  # type: ignore[no-untyped-def]
    """An argument as C takes it: an array as the pointer to its first element, a 32-bit integer by value (a C
    `int`), a 64-bit integer as an address."""
    voidp = ir.IntType(8).as_pointer()
    if isinstance(t, types.Array):
        return builder.bitcast(context.make_array(t)(context, builder, v).data, voidp)
    if t.bitwidth == 32:
        return v
    return builder.inttoptr(v, voidp)


def _typed(address: Any, args: Any) -> bool:
    if not isinstance(address, types.Integer) or not isinstance(args, types.BaseTuple):
        return False
    items: Any = args
    return all(
        isinstance(t, types.Array) or (isinstance(t, types.Integer) and getattr(t, "bitwidth", 0) in (32, 64))
        for t in items
    )


def _call(context, builder, signature, llargs, restype):  # type: ignore[no-untyped-def]
    addr, tup = llargs
    values = [
        _pointer_or_value(context, builder, t, v)
        for t, v in zip(signature.args[1], cgutils.unpack_tuple(builder, tup), strict=True)
    ]
    fnty = ir.FunctionType(restype, [v.type for v in values])
    return builder.call(builder.inttoptr(addr, fnty.as_pointer()), values)


@intrinsic
def _ccall_void(typingctx, address, args):  # type: ignore[no-untyped-def]
    """Call the C function `void f(…)` at `address` (int64) with the items of the tuple `args` (arrays as
    pointers, int32 as C ints, int64 as addresses)."""
    if not _typed(address, args):
        return None

    def codegen(context, builder, signature, llargs):  # type: ignore[no-untyped-def]
        _call(context, builder, signature, llargs, ir.VoidType())
        return context.get_dummy_value()

    return types.void(address, args), codegen


@intrinsic
def _ccall_int(typingctx, address, args):  # type: ignore[no-untyped-def]
    """`ccall_void` for a C function that returns an `int`: returns it."""
    if not _typed(address, args):
        return None

    def codegen(context, builder, signature, llargs):  # type: ignore[no-untyped-def]
        return _call(context, builder, signature, llargs, ir.IntType(32))

    return types.int32(address, args), codegen


# as compiled code calls them (the intrinsics' own signatures take numba's typing context first)
ccall_void = cast(Callable[[int, tuple[Any, ...]], None], _ccall_void)
ccall_int = cast(Callable[[int, tuple[Any, ...]], int], _ccall_int)

__all__ = ["c_function", "ccall_int", "ccall_void", "package_library"]
