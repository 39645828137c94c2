"""JSBSim's own C++ step and property reads, called from compiled code instead of through the binding.

:func:`~tepinn_flight.sim.flight.fly` logs 21 properties after every JSBSim step. Through JSBSim's
Python binding each read is a Python call (~60–90 ns), and the step and the row around them Python
too: 1.8–2 µs a step where JSBSim's ``run()`` of the agile quad takes 2.8 µs (``benchmarks/PROFILE.md``,
session 47). The binding is a thin Cython layer over exported C++ functions of its own extension
module: ``JSBSim::FGFDMExec::Run()``, ``SGPropertyNode::getDoubleValue() const`` and
``SGPropertyNode::setDoubleValue(double)``. Called directly from a numba loop with the C++ objects the
binding wraps, the same step and reads cost ~0.2 µs a row more than ``run()`` alone, with the same
numbers: the same functions on the same objects. A quad's compiled flight loop
(:mod:`tepinn_flight.sim.quad_flight_kernel`) also writes its motor commands through ``setDoubleValue``.

:class:`Stepper` runs a flight's steps and logs its rows either way; :func:`native_handles` finds the
C++ objects behind the binding's Python objects (a Cython extension type stores them after the object's
header) and checks what it found before anything is called:

* a jsbsim release whose binding this was read from (1.3), its types with that layout (``__basicsize__``;
  the executive holds the same pointer twice, as its base and as itself; every node object the same
  method table before its own pointer), and the symbols (the Itanium C++ ABI of Linux and macOS builds;
  elsewhere: not found);
* every node read natively gives the value the binding gives, on a probe property set to a value no
  model writes; a value written to the probe natively is what the binding reads back.

Anything else, ``TEPINN_JSBSIM_NATIVE=0`` in the environment or numba's compilation turned off
(``NUMBA_DISABLE_JIT``), and the binding is used; the flights are the same
bits either way (``tests/test_jsbsim_native.py``). That path costs ~10 % more of ``fly()`` than the loop before it
(session 46's, which read the row in place; here the row's reads go through one list, and a method call and the
state's hand-over come with each control update). One difference remains: a C++
exception inside ``Run()`` would end the process where the binding raises it as a Python error; JSBSim
raises none while stepping a loaded model.
"""

from __future__ import annotations

import ctypes
import functools
import operator
import os
import struct
from dataclasses import dataclass

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

#: set to "0" to use JSBSim's Python binding only (same flights; for comparison and as a way out)
ENV_SWITCH = "TEPINN_JSBSIM_NATIVE"
#: the mangled names of the C++ functions the binding's ``FGFDMExec.run``,
#: ``FGPropertyNode.get_double_value`` and ``FGPropertyNode.set_double_value`` call
SYMBOLS = {"run": "_ZN6JSBSim9FGFDMExec3RunEv", "get": "_ZNK14SGPropertyNode14getDoubleValueEv",
           "set": "_ZN14SGPropertyNode14setDoubleValueEd"}
#: the binding's object layouts this reads (jsbsim 1.3): FGFDMExec = header, FGJSBBase* base, FGFDMExec*
#: (the same pointer), one more word; FGPropertyNode = header, Cython's method table, the node
EXEC_SIZE, EXEC_BASE_WORD, EXEC_WORD = 40, 2, 3
NODE_SIZE, NODE_WORD = 32, 3
#: the jsbsim releases whose binding this layout was read from (others: the binding's path)
TESTED_VERSIONS = ("1.3.",)
#: a property no model writes, set to a value a wrong pointer would not read back
PROBE_PATH, PROBE_VALUE = "tepinn/native-probe", 0.123456789012345
#: a value written to the probe natively, which the binding must read back
PROBE_SET_VALUE = -9876.54321012345

_GET_T = ctypes.CFUNCTYPE(ctypes.c_double, ctypes.c_void_p)
_SET_T = ctypes.CFUNCTYPE(ctypes.c_bool, ctypes.c_void_p, ctypes.c_double)


@intrinsic
def _call_void(typingctx, fn_addr, obj):
    """``fn(obj)`` for the C function at address ``fn_addr`` (integers: numba passes them at the cost
    of an integer, where a ctypes function object costs ~1 µs a call to dispatch; nothing baked in, so
    the compiled code caches). Its return value, if any, is ignored."""

    def codegen(context, builder, sig, args):
        ptr_t = ir.IntType(8).as_pointer()
        fnty = ir.FunctionType(ir.VoidType(), [ptr_t])
        fn = builder.inttoptr(args[0], fnty.as_pointer())
        builder.call(fn, [builder.inttoptr(args[1], ptr_t)])
        return context.get_dummy_value()

    return types.none(types.intp, types.intp), codegen


@intrinsic
def _call_double(typingctx, fn_addr, obj):
    """``fn(obj)`` → double for the C function at address ``fn_addr`` (see :func:`_call_void`)."""

    def codegen(context, builder, sig, args):
        ptr_t = ir.IntType(8).as_pointer()
        fnty = ir.FunctionType(ir.DoubleType(), [ptr_t])
        fn = builder.inttoptr(args[0], fnty.as_pointer())
        return builder.call(fn, [builder.inttoptr(args[1], ptr_t)])

    return types.float64(types.intp, types.intp), codegen


@intrinsic
def _call_set(typingctx, fn_addr, obj, value):
    """``fn(obj, value)`` for the C++ member function at address ``fn_addr`` taking a double and returning a
    bool (``SGPropertyNode::setDoubleValue``; see :func:`_call_void`). The bool is ignored."""

    def codegen(context, builder, sig, args):
        ptr_t = ir.IntType(8).as_pointer()
        fnty = ir.FunctionType(ir.IntType(8), [ptr_t, ir.DoubleType()])
        fn = builder.inttoptr(args[0], fnty.as_pointer())
        builder.call(fn, [builder.inttoptr(args[1], ptr_t), args[2]])
        return context.get_dummy_value()

    return types.none(types.intp, types.intp, types.float64), codegen


@dataclass(frozen=True)
class NativeHandles:
    """The addresses of JSBSim's C++ ``Run``, ``getDoubleValue`` and ``setDoubleValue`` and of the executive;
    ``nodes`` keeps the binding's node objects alive beside their pointers."""

    run_fn: int
    get_fn: int
    set_fn: int
    exec_ptr: int
    nodes: tuple
    node_ptrs: np.ndarray


def _word(obj, k: int) -> int:
    return ctypes.c_void_p.from_address(id(obj) + 8 * k).value or 0


@functools.cache
def _functions():
    """The addresses of the C++ functions (``SYMBOLS``' order: run, get, set) in the binding's extension, or None."""
    import jsbsim._jsbsim as ext

    try:
        lib = ctypes.CDLL(ext.__file__)
        return tuple(ctypes.cast(getattr(lib, SYMBOLS[k]), ctypes.c_void_p).value for k in ("run", "get", "set"))
    except (OSError, AttributeError):
        return None


def unavailable() -> str | None:
    """Why no flight in this process can step JSBSim natively (the checks that need no aircraft), or None."""
    import jsbsim

    version = str(getattr(jsbsim, "__version__", ""))
    if os.environ.get(ENV_SWITCH, "1") == "0":
        return f"{ENV_SWITCH}=0"
    from numba.core import config

    if config.DISABLE_JIT:  # the kernels would run as Python, where JSBSim's C++ cannot be called
        return "numba's compilation is off (NUMBA_DISABLE_JIT)"
    if ctypes.sizeof(ctypes.c_void_p) != 8:
        return "not a 64-bit process"
    if not version.startswith(TESTED_VERSIONS):
        return f"jsbsim {version}: its binding's layout was not read (tested: {', '.join(TESTED_VERSIONS)}x)"
    if jsbsim.FGFDMExec.__basicsize__ != EXEC_SIZE or jsbsim.FGPropertyNode.__basicsize__ != NODE_SIZE:
        return f"jsbsim {version}: its binding's objects have another size"
    if _functions() is None:
        return f"jsbsim {version}: its extension does not export {', '.join(SYMBOLS.values())}"
    return None


def describe() -> str:
    """One line: how :func:`~tepinn_flight.sim.flight.fly` steps JSBSim in this process (benchmarks print it)."""
    why = unavailable()
    if why is None:
        return f"JSBSim stepped through its C++ from compiled code (sim/jsbsim_native.py; {ENV_SWITCH}=0: the binding)"
    return f"JSBSim stepped through its Python binding ({why})"


def native_handles(fdm, paths: list[str]) -> NativeHandles | None:
    """The C++ handles behind ``fdm`` and the nodes of ``paths`` (existing properties), checked; None
    where they cannot be used (see the module doc)."""
    import jsbsim

    if unavailable() is not None or type(fdm) is not jsbsim.FGFDMExec:
        return None
    exec_ptr = _word(fdm, EXEC_WORD)
    if exec_ptr == 0 or _word(fdm, EXEC_BASE_WORD) != exec_ptr:
        return None
    run_fn, get_fn, set_fn = _functions()
    get, put = _GET_T(get_fn), _SET_T(set_fn)  # the checks below call them from Python
    pm = fdm.get_property_manager()
    probe = pm.get_node(PROBE_PATH, True)
    nodes = [pm.get_node(p) for p in paths]
    if probe is None or any(n is None for n in nodes):
        return None
    probe.set_double_value(PROBE_VALUE)
    every = [probe, *nodes]
    if any(type(node) is not jsbsim.FGPropertyNode for node in every):
        return None
    # before any call: the word before the node's is Cython's method table, one for every node object, and the
    # nodes' own pointers differ from it and from each other (the paths name different properties)
    words = [_word(node, NODE_WORD) for node in every]
    table = {_word(node, NODE_WORD - 1) for node in every}
    if 0 in words or len(table) != 1 or table & set(words) or len(set(words)) != len(set(paths)) + 1:
        return None
    ptrs = np.array(words[1:], dtype=np.intp)
    if get(_word(probe, NODE_WORD)) != PROBE_VALUE:
        return None
    put(_word(probe, NODE_WORD), PROBE_SET_VALUE)  # a native write the binding reads back
    if probe.get_double_value() != PROBE_SET_VALUE:
        return None
    for node, p in zip(nodes, ptrs):
        a, b = get(int(p)), node.get_double_value()
        if not (a == b or (a != a and b != b)):
            return None
    return NativeHandles(run_fn, get_fn, set_fn, exec_ptr, tuple(nodes), ptrs)


#: the leading entries of the context array :func:`run_logged` takes (then the nodes' pointers, height
#: first, then the state's columns)
CTX_RUN, CTX_GET, CTX_EXEC, CTX_SUB, CTX_ROWS, CTX_NODES, CTX_HEAD = range(7)


@njit(cache=True)
def run_steps(run_fn, exec_ptr, n):
    """``n`` JSBSim steps."""
    for _ in range(n):
        _call_void(run_fn, exec_ptr)


@njit(cache=True)
def run_logged(ctx, i0, n, min_agl_ft, rows, state):
    """JSBSim steps ``i0`` … ``i0 + n − 1``. After each step ``i`` with ``(i + 1) % sub == 0`` the height
    (the first node) is read and, where it is above ``min_agl_ft``, the other nodes' values make row
    ``ctx[CTX_ROWS]`` of ``rows`` (then counted). ``ctx``: int64 — the functions' and the executive's
    addresses, sub, the rows filled, the number of nodes, then the nodes' pointers, then the row's columns
    of the state (−1: the height). Where the last step logs its row, ``state`` gets those columns'
    values, and where the height stops the flight, its slot (column −1) that height. Returns the step at
    which the height was not above ``min_agl_ft``, or −1."""
    run_fn, get_fn, exec_ptr, sub = ctx[CTX_RUN], ctx[CTX_GET], ctx[CTX_EXEC], ctx[CTX_SUB]
    n_nodes = ctx[CTX_NODES]
    k0 = CTX_HEAD
    s0 = CTX_HEAD + n_nodes
    m = ctx[CTX_ROWS]
    for i in range(i0, i0 + n):
        _call_void(run_fn, exec_ptr)
        if sub > 1 and (i + 1) % sub:
            continue
        h = _call_double(get_fn, ctx[k0])
        if not h > min_agl_ft:
            for j in range(ctx.shape[0] - s0):
                if ctx[s0 + j] < 0:
                    state[j] = h
            ctx[CTX_ROWS] = m
            return i
        for k in range(1, n_nodes):
            rows[m, k - 1] = _call_double(get_fn, ctx[k0 + k])
        if i == i0 + n - 1:
            for j in range(ctx.shape[0] - s0):
                c = ctx[s0 + j]
                state[j] = h if c < 0 else rows[m, c]
        m += 1
    ctx[CTX_ROWS] = m
    return -1


class Stepper:
    """A flight's JSBSim steps and logged rows: natively where :func:`native_handles` allows, else
    through the binding (the same numbers).

    ``agl_path`` is read after each logged step and decides whether the flight goes on; the row holds
    ``row_paths``' values; ``state_cols`` pick a controller's state from the last row (the height goes in
    at ``state_h_at``). ``extra_paths``: properties a compiled controller reads or writes, checked with the
    others (their pointers: :attr:`extra_ptrs`)."""

    def __init__(self, fdm, agl_path: str, row_paths: list[str], sub: int, min_agl_ft: float, capacity: int,
                 state_cols: tuple[int, ...], state_h_at: int, native: bool = True,
                 extra_paths: tuple[str, ...] = ()):  # fmt: skip
        from tepinn_flight.sim.jsbsim_env import getter

        self.sub, self.min_agl_ft = int(sub), float(min_agl_ft)
        self.state_cols, self.state_h_at = state_cols, state_h_at
        self.n_cols = len(row_paths)
        self._h = float("nan")  # the last height read (the binding's path)
        self.handles = native_handles(fdm, [agl_path, *row_paths, *extra_paths]) if native else None
        if self.handles is not None:
            hd = self.handles
            cols = [c for c in state_cols]
            cols.insert(state_h_at, -1)
            k = 1 + len(row_paths)
            self.extra_ptrs = hd.node_ptrs[k:]
            self._ctx = np.array([hd.run_fn, hd.get_fn, hd.exec_ptr, self.sub, 0, k, *hd.node_ptrs[:k], *cols],
                                 dtype=np.int64)  # fmt: skip
            self._rows = np.empty((max(1, capacity), self.n_cols))
            self._state = np.full(len(cols), np.nan)
        else:
            self._run = fdm.run
            self._agl = getter(fdm, agl_path)
            self._gets = [getter(fdm, p) for p in row_paths]
            self._pack = struct.Struct(f"={self.n_cols}d").pack
            self._last = None  # the last row's values
            self._packed = []  # one packed row of doubles per logged step, joined once at the end
            self._pick = operator.itemgetter(*state_cols)

    @property
    def native(self) -> bool:
        return self.handles is not None

    @property
    def kernel_args(self) -> tuple:
        """What a compiled loop passes to :func:`run_logged`: the context, the rows and the state arrays
        (native only)."""
        return self._ctx, self._rows, self._state

    def run(self, n: int) -> None:
        """``n`` steps, nothing logged."""
        if self.handles is not None:
            run_steps(self.handles.run_fn, self.handles.exec_ptr, n)
        else:
            run = self._run
            for _ in range(n):
                run()

    def logged(self, i0: int, n: int) -> int:
        """Steps ``i0`` … ``i0 + n − 1`` with their rows (see :func:`run_logged`); the step where the
        height was not above the floor, or −1."""
        if self.handles is not None:
            return run_logged(self._ctx, i0, n, self.min_agl_ft, self._rows, self._state)
        run, agl, gets, pack, append = self._run, self._agl, self._gets, self._pack, self._packed.append
        sub, floor = self.sub, self.min_agl_ft
        h = None
        for i in range(i0, i0 + n):
            run()
            if sub > 1 and (i + 1) % sub:
                continue
            h = agl()
            if not h > floor:
                self._h = h
                return i
            v = [g() for g in gets]
            append(pack(*v))
        if h is not None:
            self._h, self._last = h, v
        return -1

    @property
    def h(self) -> float:
        """The last height read."""
        return float(self._state[self.state_h_at]) if self.handles is not None else self._h

    def state(self) -> list:
        """The controller's state after a block whose last step logged its row: that row's columns and the
        height (the numbers the controller would read)."""
        if self.handles is not None:
            return self._state.tolist()
        out = list(self._pick(self._last))
        out.insert(self.state_h_at, self._h)
        return out

    def rows(self) -> np.ndarray:
        """The logged rows, (n, len(row_paths))."""
        if self.handles is not None:
            return self._rows[: self._ctx[CTX_ROWS]]
        return np.frombuffer(b"".join(self._packed), dtype=np.float64).reshape(len(self._packed), self.n_cols)


def warm() -> None:
    """Load (or compile) the kernels once: the campaign's forkserver calls it before it forks the workers.
    Called with nothing to do, they call nothing."""
    run_steps(0, 0, 0)
    run_logged(np.zeros(CTX_HEAD, np.int64), 0, 0, 0.0, np.empty((1, 1)), np.empty(1))
