"""A content hash of large arrays, 4-5x faster than SHA-256, for keys compared within
one process (the BVH's mesh keys, :func:`.bvh_mesh.mesh_key`; the add-on's mesh
fingerprints).

:class:`ContentHash` has hashlib's ``update`` / ``digest``. Each ``update(a)`` puts into
one SHA-256: the byte length of ``a``, then, for its bytes up to a multiple of 8, one
NH value per block of :data:`BLOCK_WORDS` 32-bit words (:func:`_nh_blocks`, a numba
kernel), then its last (< 8) bytes as they are. NH (the first layer of UMAC, Black et al.
1999) of a block ``m`` (an even number of 32-bit words) under a key ``k``::

    NH_k(m) = sum over i of ((m[2i] + k[2i]) mod 2^32) * ((m[2i + 1] + k[2i + 1]) mod 2^32)
              mod 2^64

is 2^-32-almost-universal over messages of equal length: for two different blocks of the
same length, the probability over a uniformly random key that their NH values are equal is
at most 2^-32, whatever the blocks are. :data:`LANES` (4) NH values per block with keys
shifted by 4 words (UMAC's Toeplitz construction, the 128-bit key shifts of RFC 4418's
L1-HASH) bring it to 2^-128. The key is drawn at
random once per process (``secrets``), so the bound holds for any data, not only for data
"unrelated to a fixed key"; it is why the digests must not be compared between processes
(they are not: mesh keys and fingerprints live only in the process).

Why two different inputs collide with probability at most 2^-128 (+ SHA-256's): the
SHA-256 input is a sequence of (length, NH values, tail) records, which is read back
unambiguously (the length fixes how many NH values and tail bytes follow). Two update
sequences that differ either differ in a length or a tail byte (then their SHA-256 inputs
differ: a SHA-256 collision, taken as impossible) or have a first differing block of equal
length (NH's bound: equal values with probability <= 2^-128; if the values differ, the
SHA-256 inputs differ). Two meshes of a process are compared a few thousand times at
most: the chance of a wrong "same mesh" is below 10^-30.

Speed: the kernel reads each 8 bytes once and does :data:`LANES` multiplies (vectorised
by LLVM); SHA-256 sees 32 bytes per :data:`BLOCK_WORDS` words (0.05 %): 5-7 GB/s here
against SHA-256's 1.4 (32 MB, one thread). The blocks are independent: an update of
:data:`SPLIT_BLOCKS` blocks or more hashes its second half on another thread
(:class:`~rstrace_engine.beside.Beside`) while this one hashes the first, into the same
rows of NH values: the same digest.
"""

from __future__ import annotations

import hashlib
import secrets

import numpy as np
from numba import njit

from ..beside import Beside

#: 32-bit words per NH block (64 KB): :data:`LANES` 64-bit NH values per block go to SHA-256.
BLOCK_WORDS = 1 << 14
#: NH values per block (keys shifted by :data:`SHIFT` words): collision bound 2^-32 each.
LANES = 4
SHIFT = 4

#: Blocks from which an update hashes its two halves on two threads (2 MB: below, the
#: hand-off costs more than half the hash)
SPLIT_BLOCKS = 32

#: The process's NH key: BLOCK_WORDS + SHIFT * (LANES - 1) random 32-bit words.
_KEY = np.frombuffer(secrets.token_bytes(4 * (BLOCK_WORDS + SHIFT * (LANES - 1))),
                     np.uint32).copy()
_KEY.flags.writeable = False


@njit(cache=True, nogil=True)
def _nh_blocks(words, key, out):
    """NH of each block of ``BLOCK_WORDS`` words of ``words`` (1-d uint32, read-only,
    an even count; the last block may be shorter) under ``key`` and ``key`` shifted by
    1, 2 and 3 times ``SHIFT`` words: ``out[b, 0:4]`` (uint64, (blocks, LANES)). Integer
    arithmetic only: wrapping sums of 32-bit additions' products."""
    n = words.shape[0]
    for b in range(out.shape[0]):
        s = b * BLOCK_WORDS
        pairs = (min(n - s, BLOCK_WORDS)) // 2
        a0 = np.uint64(0)
        a1 = np.uint64(0)
        a2 = np.uint64(0)
        a3 = np.uint64(0)
        for q in range(pairs):
            i = s + 2 * q
            j = 2 * q
            m0 = words[i]
            m1 = words[i + 1]
            a0 += (np.uint64(np.uint32(m0 + key[j]))
                   * np.uint64(np.uint32(m1 + key[j + 1])))
            a1 += (np.uint64(np.uint32(m0 + key[j + SHIFT]))
                   * np.uint64(np.uint32(m1 + key[j + SHIFT + 1])))
            a2 += (np.uint64(np.uint32(m0 + key[j + 2 * SHIFT]))
                   * np.uint64(np.uint32(m1 + key[j + 2 * SHIFT + 1])))
            a3 += (np.uint64(np.uint32(m0 + key[j + 3 * SHIFT]))
                   * np.uint64(np.uint32(m1 + key[j + 3 * SHIFT + 1])))
        out[b, 0] = a0
        out[b, 1] = a1
        out[b, 2] = a2
        out[b, 3] = a3


def _read_only(a: np.ndarray) -> np.ndarray:
    """A read-only view of ``a`` (one kernel signature for Blender's read-only views and
    the engine's own arrays alike)."""
    if not a.flags.writeable:
        return a
    v = a.view()
    v.flags.writeable = False
    return v


def _nh_halves(words: np.ndarray, out: np.ndarray) -> None:
    """:func:`_nh_blocks` of ``words`` into ``out``, the second half of the blocks on
    another thread from :data:`SPLIT_BLOCKS` blocks (each block's value is computed
    alone: the same rows whichever thread computes them)."""
    nb = len(out)
    if nb < SPLIT_BLOCKS:
        _nh_blocks(words, _KEY, out)
        return
    half = nb // 2
    job = Beside(_nh_blocks, words[half * BLOCK_WORDS:], _KEY, out[half:])
    try:
        _nh_blocks(words[:half * BLOCK_WORDS], _KEY, out[:half])
    except BaseException:
        job.drop()
        raise
    job.result()


class ContentHash:
    """hashlib-like: ``update(array or bytes)``, ``digest()`` (16 bytes). Module
    docstring: what it hashes and why equal digests mean equal inputs."""

    def __init__(self) -> None:
        self._sha = hashlib.sha256(b"rstrace NH/SHA-256 v1")

    def update(self, data) -> None:
        raw = np.ascontiguousarray(np.frombuffer(data, np.uint8) if isinstance(
            data, (bytes, bytearray, memoryview)) else data).reshape(-1)
        u8 = raw.view(np.uint8) if raw.size else np.zeros(0, np.uint8)
        n = u8.size
        self._sha.update(n.to_bytes(8, "little"))
        bulk = n - n % 8
        if bulk:
            if u8.ctypes.data % 4:  # (not on a 4-byte boundary: an aligned copy)
                u8 = u8.copy()
            words = _read_only(u8[:bulk].view(np.uint32))
            out = np.empty(((len(words) + BLOCK_WORDS - 1) // BLOCK_WORDS, LANES), np.uint64)
            _nh_halves(words, out)
            self._sha.update(out)
        self._sha.update(u8[bulk:].tobytes())

    def digest(self) -> bytes:
        return self._sha.digest()[:16]
