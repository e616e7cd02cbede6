"""What one factorisation hands to the next of the same pattern (docs/sph.md § 5, § 11).

A study's realizations on one layout differ in the moduli, not in which unknowns couple:
each realization's first system has nearly the sparsity pattern of the last one's. The work
that depends on the pattern alone — the direct solver's nested-dissection order, PARDISO's
analysis (METIS's order and the symbolic factorisation) — is kept in a ``SymbolicStore`` and
reused: at MS2's 40,709 particles the analysis is 1 s of PARDISO's 3 s factorisation
(BENCHMARKS.md "SPH: what bounds one MS2 solve").

"Nearly": SciPy's sparse products drop the sums that come out exactly zero, and on a regular
lattice with one modulus per phase the symmetric couplings cancel to zero or to a rounding
error depending on the moduli (MS2 on benchmarks/sph_scaling.py's plate at 10,353
particles, one ad hoc run: 1,719,055 to 1,719,264 entries over six draws of the two moduli,
1,719,572 with a random field on every particle). So an order is kept under a hash of the
exact pattern and of the points it split (``pattern_key``): the direct solver's numbers stay
those of a fresh order, bit for bit, and a flickering pattern orders afresh. A PARDISO analysis is
kept with its pattern and serves any matrix whose entries it covers (``embedded``: the
missing ones factorised as explicit zeros), or whose entries outside it are rounding
errors (left out of the single-precision factors, which every solve refines against the
matrix itself); a matrix not covered is analysed on the union of both patterns
(``covering_pattern``), so that the kept pattern grows to cover it. The factors can differ in
rounding with the analysis kept, as they already do with MKL's threads (docs/sph.md § 5).
"""

from __future__ import annotations

import hashlib
import threading
import weakref
from collections import OrderedDict
from typing import Callable

import numpy as np
import scipy.sparse as sp
from numba import njit

#: a kept pattern serves a matrix, or grows to cover it, while it holds at most this fraction
#: more entries than the matrix: the flicker above was 0.03 % (ad hoc); a kept pattern far
#: larger is another system's, whose fill this one should not pay
PATTERN_SLACK = 0.01
#: an entry of A the kept pattern lacks is left out of the factors if it is at most this
#: fraction of A's largest: a sum cancelled to a rounding error (~1e-16 of its terms), 600
#: times below single precision's unit roundoff, which the factors' other errors already
#: exceed; every solve is refined against A itself (refinement.py), the entry included
NEGLIGIBLE = 1e-10
#: patterns kept: a study's first system and one more (two layouts alternating, or the
#: first system of a run whose later systems reuse nothing)
CAPACITY = 2


def pattern_key(kind: str, A, *arrays) -> tuple[str, bytes]:
    """(kind, a hash of A's shape, format and index arrays, and of ``arrays``)."""
    digest = hashlib.sha256()
    digest.update(f"{A.format} {A.shape[0]} {A.shape[1]}".encode())
    for array in (A.indptr, A.indices, *arrays):
        array = np.ascontiguousarray(array)
        digest.update(f"{array.dtype.str}{array.shape}".encode())
        digest.update(array.view(np.uint8).ravel())
    return kind, digest.digest()


@njit(cache=True)
def _positions(a_indptr, a_indices, s_indptr, s_indices):
    """Where each entry of A sits in S (CSR patterns of one shape, sorted indices), -1 where S
    lacks it: one merge of each row."""
    positions = np.full(a_indices.size, -1, dtype=np.int64)
    for row in range(a_indptr.size - 1):
        k, end = s_indptr[row], s_indptr[row + 1]
        for entry in range(a_indptr[row], a_indptr[row + 1]):
            column = a_indices[entry]
            while k < end and s_indices[k] < column:
                k += 1
            if k < end and s_indices[k] == column:
                positions[entry] = k
                k += 1
    return positions


def embedded(A, indptr, indices, dtype=np.float64):
    """A's entries on the CSR pattern (indptr, indices), zeros where A has none; None if the
    pattern exceeds A's by more than PATTERN_SLACK or lacks an entry of A above NEGLIGIBLE
    times A's largest (those below are left out). A: CSR, sorted."""
    if indptr.size != A.indptr.size or indices.size > (1.0 + PATTERN_SLACK) * A.nnz:
        return None
    if np.array_equal(indptr, A.indptr) and np.array_equal(indices, A.indices):
        return np.ascontiguousarray(A.data, dtype=dtype)
    positions = _positions(A.indptr, A.indices, indptr, indices)
    inside = positions >= 0
    if not inside.all():
        scale = max(float(A.data.max(initial=0.0)), -float(A.data.min(initial=0.0)))
        if np.abs(A.data[~inside]).max() > NEGLIGIBLE * scale:
            return None
    data = np.zeros(indices.size, dtype=dtype)
    data[positions[inside]] = A.data[inside]
    return data


def covering_pattern(A, indptr, indices):
    """The union of A's CSR pattern and (indptr, indices) if it exceeds A's by at most
    PATTERN_SLACK, else A's own: (indptr, indices), sorted."""
    if indptr.size == A.indptr.size:
        ones = sp.csr_matrix((np.ones(indices.size), indices, indptr), shape=A.shape)
        union = (ones + sp.csr_matrix((np.ones(A.nnz), A.indices, A.indptr), shape=A.shape))
        if union.nnz <= (1.0 + PATTERN_SLACK) * A.nnz:     # positive sums: none dropped
            union.sort_indices()
            return union.indptr, union.indices
    return A.indptr, A.indices


class SymbolicStore:
    """At most ``capacity`` items of symbolic work, each under a key (``pattern_key``, or the
    system's size for a PARDISO analysis), the least recently used released first. An item
    is shared (``lookup``: an immutable order) or handed to one factorisation at a time
    (``take``: a PARDISO handle, which its factorisation overwrites) and given back with
    ``keep``. Safe to share between threads: two realizations of one pattern at once take
    one item and make another."""

    def __init__(self, capacity: int = CAPACITY):
        self.capacity = int(capacity)
        self._items: OrderedDict = OrderedDict()      # key -> (item, release)
        # re-entrant: a factorisation collected while this thread holds the lock gives its
        # analysis back through ``keep``
        self._lock = threading.RLock()
        #: how many lookups and takes found their pattern
        self.hits = 0
        # at collection or at exit, before the modules a release calls are torn down
        weakref.finalize(self, _release_all, self._items, self._lock)

    def lookup(self, key):
        """The item kept under ``key`` (left in the store), or None."""
        with self._lock:
            if key not in self._items:
                return None
            self._items.move_to_end(key)
            self.hits += 1
            return self._items[key][0]

    def take(self, key):
        """The item kept under ``key``, removed from the store, or None."""
        with self._lock:
            entry = self._items.pop(key, None)
            if entry is not None:
                self.hits += 1
            return None if entry is None else entry[0]

    def keep(self, key, item, release: Callable[[object], None] = lambda item: None):
        """Keep ``item`` under ``key``; ``release(item)`` frees it when it is dropped — at
        once if ``key`` already holds one, or when the store outgrows its capacity."""
        dropped = []
        with self._lock:
            if key in self._items:
                dropped.append((item, release))
            else:
                self._items[key] = (item, release)
                while len(self._items) > self.capacity:
                    dropped.append(self._items.popitem(last=False)[1])
        for old, free in dropped:
            free(old)

    def clear(self):
        """Release every item."""
        _release_all(self._items, self._lock)

    def __len__(self) -> int:
        return len(self._items)

    def __reduce__(self):
        # a copy in another process starts empty: what is kept (MKL's handles, orders) is
        # this process's, and the lock cannot be pickled
        return SymbolicStore, (self.capacity,)


def _release_all(items: OrderedDict, lock):
    with lock:
        entries = list(items.values())
        items.clear()
    for item, release in entries:
        release(item)
