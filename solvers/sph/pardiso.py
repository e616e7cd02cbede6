"""Intel MKL PARDISO, the optional extra ``uqflow[pardiso]`` (docs/sph.md § 5, § 11).

A multithreaded supernodal LU of a real unsymmetric matrix (MKL's mtype 11) in METIS's
nested-dissection order, with MKL's default scaling, matching and pivot perturbation, called
through ctypes. In single precision the analysis reads the pattern alone, and a
``symbolic.SymbolicStore`` hands it on: a later matrix whose entries the analysed pattern
covers is factorised on the analysed handle (PARDISO's phase 22 alone), once the
predecessor's factors are released.

pypardiso supplies MKL's runtime library (it knows where pip puts it), not the calls: its
wrapper copies the index arrays to 1-based ones and compares the whole matrix with
the factorised one at every solve (0.3 s a solve at 40,709 particles, where the solve itself
takes 0.05 s), and it has no single precision, which halves the factorisation's time.
"""

from __future__ import annotations

import ctypes
import os
import time
import weakref

import numpy as np
import scipy.sparse as sp

from solvers.sph.symbolic import covering_pattern, embedded

INSTALL = "pip install 'uqflow[pardiso]'"
REAL_UNSYMMETRIC = 11
ANALYSE, FACTORISE, SOLVE, RELEASE_FACTORS, RELEASE = 11, 22, 33, 0, -1
#: PARDISO's error codes (MKL reference, "pardiso"), for the one-line error
ERRORS = {-1: "input inconsistent", -2: "not enough memory", -3: "reordering problem",
          -4: "zero pivot, numerical factorisation or iterative refinement problem",
          -5: "unclassified (internal) error", -6: "reordering failed",
          -7: "diagonal matrix is singular", -8: "32-bit integer overflow problem",
          -9: "not enough memory for out-of-core", -10: "error opening out-of-core files",
          -11: "read/write error with out-of-core files", -12: "wrong pardiso_64 call"}

_library = None
#: PARDISO reads a user's permutation only if iparm[4] asks it to (here it never does)
_NO_PERMUTATION = np.zeros(1, dtype=np.int32)


class PardisoError(ArithmeticError):
    """PARDISO is not installed, or refused or failed a phase."""


def _mkl():
    """MKL's runtime library, found once. When the loader does not know it (pip's MKL),
    pypardiso finds it by a recursive search of the environment, 0.2 s, unless
    PYPARDISO_MKL_RT (its documented setting) names it: the path found is set there for any
    process started from this one."""
    global _library
    if _library is None:
        try:
            import pypardiso
        except ImportError:
            raise PardisoError(f"linear_solver 'pardiso' needs pypardiso and MKL "
                               f"({INSTALL})") from None
        path = pypardiso.PyPardisoSolver().libmkl._name
        os.environ.setdefault("PYPARDISO_MKL_RT", path)
        # a library object of our own: pypardiso's sets argument types on its functions
        library = ctypes.CDLL(path)
        library.pardiso.restype = None
        _library = library
    return _library


def _parameters(single: bool) -> np.ndarray:
    """iparm: MKL's defaults for mtype 11 set explicitly (iparm[0] = 1 makes PARDISO read
    them), with zero-based indices and the precision chosen. In single precision without
    scaling and matching: every solve through those factors is refined against A (and A
    factorised in double if refinement stalls), which is the robustness matching buys, and
    skipping it took about 0.6 s off the 1.5 s analysis of MS2's and the penalty's systems of
    benchmarks/sph_scaling.py's plate at 40,709 particles (one measurement, same refinement
    steps)."""
    iparm = np.zeros(64, dtype=np.int32)
    iparm[0] = 1        # these values, not PARDISO's defaults
    iparm[1] = 2        # METIS nested dissection
    iparm[9] = 13       # a pivot below 1e-13 ||A|| is perturbed to it
    iparm[10] = int(not single)     # scaling and ...
    iparm[12] = int(not single)     # ... weighted matching: large entries onto the diagonal
    iparm[17] = -1      # report the entries of L + U in iparm[17]
    iparm[27] = int(single)
    iparm[34] = 1       # zero-based indices, as scipy's
    return iparm


class PardisoLU:
    """PARDISO's factors of the CSR matrix A in float64 or float32 (``dtype``), solving
    A x = b for one b or a block of columns (x always float64). The factors live in MKL's
    memory until this object is collected."""

    def __init__(self, A, dtype=np.float64, store=None):
        library = _mkl()
        A = sp.csr_matrix(A)
        if not A.has_sorted_indices:        # PARDISO's requirement; a sorted copy
            A = A.sorted_indices()
        self.n = A.shape[0]
        empty = np.flatnonzero(np.diff(A.indptr) == 0)
        if empty.size:              # PARDISO would fail on it without saying where
            raise PardisoError(f"the system of {self.n} unknowns is singular (empty row "
                               f"{int(empty[0])})")
        self.dtype = np.dtype(dtype)
        key, analysed, pattern = None, None, (A.indptr, A.indices)
        data = A.data
        if store is not None and self.dtype == np.float32:
            # without scaling and matching (_parameters) the analysis reads the pattern alone
            key = ("pardiso", self.n)
            analysed = store.take(key)
            if analysed is not None:
                data = embedded(A, *analysed[2:])
                if data is None:        # not covered: analyse the union (symbolic.py)
                    kept, analysed = analysed, None
                    _release(library.pardiso, *kept[:2], self.n)
                    pattern = covering_pattern(A, *kept[2:])
                    data = embedded(A, *pattern)
        if analysed is not None:
            # the handle and the pattern it was analysed for, kept together
            self._handle, self._iparm, self._indptr, self._indices = analysed
        else:
            self._indptr = np.ascontiguousarray(pattern[0], dtype=np.int32)
            self._indices = np.ascontiguousarray(pattern[1], dtype=np.int32)
            self._handle = np.zeros(64, dtype=np.int64)
            self._iparm = _parameters(self.dtype == np.float32)
        self._data = np.ascontiguousarray(data, dtype=self.dtype)
        self._call = library.pardiso
        #: whether the analysis came from the store (PARDISO's phase 11 skipped)
        self.analysis_reused = analysed is not None
        # MKL's memory is released with the handle, whichever phase fails; a handle whose
        # factorisation succeeded goes back to the store with its analysis alone
        factorised = []
        self._finalizer = weakref.finalize(
            self, _retire, library.pardiso, (self._handle, self._iparm, self._indptr,
                                             self._indices), self.n, factorised,
            None if key is None else weakref.ref(store), key)
        empty = np.zeros(1, dtype=self.dtype)
        t0 = time.perf_counter()
        if analysed is None:
            self._phase(ANALYSE, empty, empty, 1)
        t1 = time.perf_counter()
        self._phase(FACTORISE, empty, empty, 1)
        factorised.append(True)
        #: seconds of the analysis (METIS's order, the symbolic factorisation; 0 when
        #: reused) and of the numerical factorisation (benchmarks/sph_factor_floor.py)
        self.seconds = {"analysis": t1 - t0, "factorisation": time.perf_counter() - t1}
        self.nnz = int(self._iparm[17])

    def solve(self, b):
        b = np.asarray(b)
        columns = 1 if b.ndim == 1 else b.shape[1]
        rhs = np.asfortranarray(b, dtype=self.dtype)
        x = np.zeros_like(rhs)
        self._phase(SOLVE, rhs, x, columns)
        return np.ascontiguousarray(x, dtype=float)

    def _phase(self, phase, b, x, columns):
        error = _run(self._call, self._handle, self._iparm, self.n, phase, self._data,
                     self._indptr, self._indices, b, x, columns)
        if error:
            raise PardisoError(f"PARDISO phase {phase} failed on {self.n} unknowns: error "
                               f"{error} ({ERRORS.get(error, 'unknown')})")


def _run(call, handle, iparm, n, phase, data, indptr, indices, b, x, columns) -> int:
    error = ctypes.c_int32(0)
    one = ctypes.c_int32(1)
    call(_address(handle), ctypes.byref(one), ctypes.byref(one),
         ctypes.byref(ctypes.c_int32(REAL_UNSYMMETRIC)), ctypes.byref(ctypes.c_int32(phase)),
         ctypes.byref(ctypes.c_int32(n)), _address(data), _address(indptr), _address(indices),
         _address(_NO_PERMUTATION), ctypes.byref(ctypes.c_int32(columns)), _address(iparm),
         ctypes.byref(ctypes.c_int32(0)), _address(b), _address(x), ctypes.byref(error))
    return int(error.value)


def _address(array):
    """The array's data as a C pointer (the caller keeps the array alive). Not
    ``ndarray.ctypes.data_as``: its ``ctypes.cast`` leaves a reference cycle holding the
    array until the cyclic collector runs, so PARDISO's single-precision copy of A (44 MB for
    MS2's 11.0 million entries at 40,709 particles) and every right-hand side outlived their
    factors and solves by an unknown time."""
    return ctypes.c_void_p(array.ctypes.data)


def _release(call, handle, iparm, n, phase=RELEASE):
    empty = np.zeros(1)
    indptr = np.zeros(n + 1, dtype=np.int32)
    _run(call, handle, iparm, n, phase, empty, indptr, np.zeros(1, dtype=np.int32),
         empty, empty, 1)


def _retire(call, analysed, n, factorised, store_ref, key):
    """A dropped factorisation's MKL memory: all of it, or, if it succeeded and its store
    is alive, its factors alone, the analysed handle given back to the store."""
    handle, iparm = analysed[:2]
    store = None if store_ref is None else store_ref()
    if store is None or not factorised:
        _release(call, handle, iparm, n)
        return
    _release(call, handle, iparm, n, RELEASE_FACTORS)
    store.keep(key, analysed, lambda kept: _release(call, kept[0], kept[1], n))
